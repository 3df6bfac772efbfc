"""A material's Volume socket → the core's homogeneous medium (constant inputs; Cycles'
meanings, docs/design/volumes.md) (a ShaderCompiler mixin)."""

import numpy as np

from .graph import _Cycle


class VolumeShaders:
    """The volume shader nodes, summed into one medium (ShaderCompiler mixin)."""

    def volume(self, socket, name):
        """The material's Volume: None (no volume), ((r, g, b), density) for a lone Volume
        Absorption (the core's Beer's law, as before volumes), or a dict of the homogeneous
        medium's sigma_a, sigma_s, g and emission (per unit length, Cycles' meanings)."""
        src = self.source(socket, ())
        if src is None or src[0] == "default":
            return None
        _, node, out, ctx = src
        if node.type == 'VOLUME_ABSORPTION':
            color = self.const_input(node, "Color", ctx, "color").const[:3]
            density = self.const_input(node, "Density", ctx, "float").const[0]
            return (tuple(color), density)
        acc = {"sigma_a": np.zeros(3), "sigma_s": np.zeros(3), "emission": np.zeros(3), "gs": np.zeros(3),
               "g": set()}
        self._volume_node(node, ctx, 1.0, acc, set())
        ss = acc["sigma_s"]
        if len(acc["g"]) > 1:
            self.problem(f"volume of '{name}': scatterings of different anisotropies are combined "
                         "into one (their scattering-weighted mean)")
        g = float(acc["gs"].sum() / ss.sum()) if ss.sum() > 0.0 else 0.0
        vol = {k: tuple(float(x) for x in acc[k]) for k in ("sigma_a", "sigma_s", "emission")}
        vol["g"] = g
        if not any(any(v) for v in (vol["sigma_a"], vol["sigma_s"], vol["emission"])):
            return None
        return vol

    def _clean(self, node, what, values):
        """Volume coefficients: NaN, infinite or negative values mean nothing: 0, with a warning."""
        v = np.asarray(values, dtype=np.float64)
        bad = ~np.isfinite(v) | (v < 0.0)
        if bad.any():
            self.problem(f"'{node.name}': {what} is negative or not a number (clamped to 0)")
            v = np.where(bad, 0.0, v)
        return v

    def _volume_node(self, node, ctx, w, acc, visiting):
        """Adds what volume shader `node` (weight w, a constant) puts into the medium."""
        key = (node.as_pointer(), self.ctx_key(ctx))
        if key in visiting:
            raise _Cycle(node.name)
        visiting = visiting | {key}

        def const(name, kind):
            v = self.const_input(node, name, ctx, kind).const
            return v[:3] if kind == "color" else v[0]

        def sub(socket, weight):
            src = self.source(socket, ctx)
            if src is None or src[0] == "default" or weight == 0.0:
                return
            _, n, out, nctx = src
            if out.type != 'SHADER':
                self.problem(f"a value linked into the volume shader input of '{node.name}' (ignored)")
                return
            self._volume_node(n, nctx, weight, acc, visiting)

        t = node.type
        if t == 'ADD_SHADER':
            sub(node.inputs[0], w)
            sub(node.inputs[1], w)
        elif t == 'MIX_SHADER':
            f = min(max(float(const("Fac", "float")), 0.0), 1.0)
            sub(node.inputs[1], w * (1.0 - f))
            sub(node.inputs[2], w * f)
        elif t == 'VOLUME_ABSORPTION':
            c = np.minimum(self._clean(node, "Color", const("Color", "color")), 1.0)
            d = self._clean(node, "Density", [const("Density", "float")])[0]
            acc["sigma_a"] += w * (1.0 - c) * d
        elif t == 'VOLUME_SCATTER':
            phase = getattr(node, "phase", 'HENYEY_GREENSTEIN')
            if phase != 'HENYEY_GREENSTEIN':
                self.problem(f"'{node.name}': the {phase} phase function is not supported "
                             "(Henyey-Greenstein)")
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0]
            g = float(const("Anisotropy", "float")) if "Anisotropy" in node.inputs else 0.0
            self._add_scatter(acc, w * c * d, g)
        elif t == 'PRINCIPLED_VOLUME':
            # Cycles' svm_node_principled_volume: scattering colour * density; extinction adds
            # (1 - colour)(1 - sqrt(absorption colour)) * density.
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0] * w
            g = float(const("Anisotropy", "float"))
            ac = np.sqrt(self._clean(node, "Absorption Color", const("Absorption Color", "color")))
            self._add_scatter(acc, c * d, g)
            acc["sigma_a"] += np.maximum(1.0 - c, 0.0) * np.maximum(1.0 - ac, 0.0) * d
            strength = float(const("Emission Strength", "float"))
            ec = self._clean(node, "Emission Color", const("Emission Color", "color"))
            if np.isfinite(strength) and strength > 0.0:
                acc["emission"] += w * strength * ec
            if float(const("Blackbody Intensity", "float")) != 0.0:
                self.problem(f"'{node.name}': blackbody emission is not supported (ignored)")
        elif t == 'EMISSION':  # an Emission shader in a Volume emits from the whole volume
            c = self._clean(node, "Color", const("Color", "color"))
            strength = self._clean(node, "Strength", [const("Strength", "float")])[0]
            acc["emission"] += w * strength * c
        else:
            self.problem(f"volume '{node.name}' ({node.bl_idname}) is not supported (ignored)")

    def _add_scatter(self, acc, sigma_s, g):
        g = float(g) if np.isfinite(g) else 0.0
        if not np.any(sigma_s > 0.0):
            return
        acc["sigma_s"] += sigma_s
        acc["gs"] += sigma_s * g
        acc["g"].add(round(g, 6))
