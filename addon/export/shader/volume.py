"""A material's Volume socket → the core's medium (Cycles' meanings, docs/design/volumes.md)
(a ShaderCompiler mixin): constant inputs give the homogeneous medium as before; inputs that
vary in space (textures, coordinates, maths) give a volume program, value ops evaluated at
points inside the medium ending in a ("closure", "volume", ...) op of its coefficients."""

import numpy as np

from .graph import _Cycle
from .registers import MAX_REGISTERS, allocate_registers, eliminate_dead_code
from .values import ONE, ZERO, const_color, const_float


def _attr_name(node, socket):
    """Principled Volume's grid name inputs (string sockets in 4.5: "Density Attribute", ...)."""
    s = node.inputs.get(socket)
    return str(getattr(s, "default_value", "") or "") if s is not None else ""


# The core's limits on one medium's phase functions (scene/shader.h kMaxPhaseLobes, kMaxVolumeLobeInputs).
MAX_PHASE_LOBES = 4
MAX_LOBE_INPUTS = 6
# Volume Scatter's phase → the core's lobe type and the inputs that are its parameters (Cycles'
# svm_alloc_closure_volume_scatter: Fournier-Forand (Backscatter, IOR), Draine (Anisotropy,
# Alpha), Mie (Diameter)).
PHASES = {
    'HENYEY_GREENSTEIN': ("hg", ("Anisotropy",)),
    'FOURNIER_FORAND': ("ff", ("Backscatter", "IOR")),
    'DRAINE': ("draine", ("Anisotropy", "Alpha")),
    'RAYLEIGH': ("rayleigh", ()),
    'MIE': ("mie", ("Diameter",)),
}


def _phase_of(node):
    """(core type, input names) of a Volume Scatter or Volume Coefficients node's phase;
    Principled Volume's is HG."""
    if node.type not in ('VOLUME_SCATTER', 'VOLUME_COEFFICIENTS'):
        return PHASES['HENYEY_GREENSTEIN']
    return PHASES.get(getattr(node, "phase", 'HENYEY_GREENSTEIN'), PHASES['HENYEY_GREENSTEIN'])


class _Varying(Exception):
    """A volume input is not constant: the medium needs a program."""


# Cycles' svm_node_principled_volume: Stefan-Boltzmann's constant scaled as its blackbody
# emission is (5.670373e-8 * 1e-6 / pi).
BLACKBODY_SIGMA = 5.670373e-8 * 1e-6 / np.pi


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
        if self.volume_grids is not None:  # a volume object's grids vary: always a program
            return self.volume_program(socket, name)
        n_problems = len(self.problems)
        # (A cache of its own: values the surface cached may differ in a volume, Point Density's.)
        saved = (self.in_volume, self.cache)
        self.in_volume, self.cache = True, {}
        try:
            if node.type == 'VOLUME_ABSORPTION':
                color = self._const_or_raise(node, "Color", ctx, "color")
                density = self._const_or_raise(node, "Density", ctx, "float")
                return (tuple(color), density)
            acc = {"sigma_a": np.zeros(3), "sigma_s": np.zeros(3), "emission": np.zeros(3), "phases": {}}
            self._volume_node(node, ctx, 1.0, acc, set())
        except _Varying:
            del self.problems[n_problems:]  # the program reports its own
            return self.volume_program(socket, name)
        finally:
            self.in_volume, self.cache = saved
        vol = {k: tuple(float(x) for x in acc[k]) for k in ("sigma_a", "sigma_s", "emission")}
        phases = acc["phases"]
        if len(phases) <= 1 and all(t == "hg" for t, _ in phases):
            vol["g"] = next(iter(phases))[1][0] if phases else 0.0  # one HG: the medium as before
        else:
            # Several phase functions (or one other than HG): each with its scattering, mixed
            # per channel by the core (docs/design/volumes.md "Several phase closures").
            self._check_lobes(name, [t for t, _ in phases])
            vol["phases"] = [(t, tuple(float(x) for x in ss), tuple(params))
                             for (t, params), ss in phases.items()]
        if not any(any(v) for v in (vol["sigma_a"], vol["sigma_s"], vol["emission"])):
            return None
        return vol

    def _check_lobes(self, name, types):
        """The core mixes at most MAX_PHASE_LOBES phase functions per medium (Mie is two)."""
        n = sum(2 if t == "mie" else 1 for t in types)
        if n > MAX_PHASE_LOBES or len(types) > MAX_LOBE_INPUTS:
            self.problem(f"volume of '{name}': more than {MAX_PHASE_LOBES} different phase functions "
                         "(the further ones scatter as the last that fits)")

    def _const_or_raise(self, node, name, ctx, kind):
        """A constant input's value (colour: rgb, float: the value); _Varying where it is linked
        to something that varies."""
        v = self.value(node.inputs[name], ctx, kind)
        if v is None or not v.is_const:
            raise _Varying()
        return v.const[:3] if kind == "color" else v.const[0]

    # -------------------------------------------------- heterogeneous: a volume program

    def volume_program(self, socket, name):
        """The Volume as a program of the core (a list of ops ending in the "volume" closure), or
        the homogeneous dict where every coefficient folded to a constant after all (e.g. a
        constant Blackbody), or None (nothing)."""
        saved = (self.ops, self.const_regs, self.cache, self.in_volume)
        self.ops, self.const_regs, self.cache, self.in_volume = [], {}, {}, True
        try:
            acc = {"sigma_a": None, "sigma_s": None, "emission": None, "scatter": []}
            src = self.source(socket, ())
            _, node, out, ctx = src
            self._volume_prog_node(node, ctx, ONE, acc, set())
            scatter = acc["scatter"]
            outs = {k: acc[k] for k in ("sigma_a", "sigma_s", "emission") if acc[k] is not None}
            lobes = {}  # the phase (type, constant parameters or an id) -> [ss, type, params]
            for i, (ss, t, params) in enumerate(scatter):
                key = (t, tuple(v.const[0] for v in params)) if all(v.is_const for v in params) else i
                if key in lobes:
                    lobes[key][0] = self.mix("ADD", ONE, lobes[key][0], ss)
                else:
                    lobes[key] = [ss, t, params]
            if len(lobes) <= 1 and all(t == "hg" for _, t, _ in lobes.values()):
                outs["g"] = next(iter(lobes.values()))[2][0] if lobes else ZERO  # one HG, as before
                lobes = []
            else:
                # Several phase functions (or one other than HG): each lobe's scattering and its
                # parameters (g; g, alpha; backscatter, IOR; diameter) as a vector.
                lobes = list(lobes.values())
                self._check_lobes(name, [t for _, t, _ in lobes])
                lobes = lobes[:MAX_LOBE_INPUTS]
                outs.pop("sigma_s", None)
                for k, (ss, t, params) in enumerate(lobes):
                    p = list(params) + [ZERO] * (3 - len(params))
                    outs[f"ss{k}"] = self.as_color(ss)
                    outs[f"{t}{k}"] = self.combine(self.as_float(p[0]), self.as_float(p[1]), self.as_float(p[2]),
                                                   "vector")
            if all(v.is_const for v in outs.values()):  # homogeneous after all
                clean = lambda v: tuple(max(float(x), 0.0) if np.isfinite(x) else 0.0 for x in v.const[:3])
                vol = {k: clean(outs.get(k, ZERO)) for k in ("sigma_a", "sigma_s", "emission")}
                if lobes:
                    vol["phases"] = [(t, clean(outs[f"ss{k}"]), tuple(float(v.const[0]) for v in params))
                                     for k, (_, t, params) in enumerate(lobes)]
                    vol["sigma_s"] = tuple(map(float, np.sum([ss for _, ss, _ in vol["phases"]], axis=0)))
                else:
                    g = outs["g"]
                    vol["g"] = float(g.const[0]) if np.isfinite(g.const[0]) else 0.0
                if not any(any(vol[k]) for k in ("sigma_a", "sigma_s", "emission")):
                    return None
                return vol
            ops = self.ops + [("closure", "volume", None, {k: self.reg(v) for k, v in outs.items()})]
            program = allocate_registers(eliminate_dead_code(ops))
            if program is None:
                self.problem(f"the volume of '{name}' needs more than {MAX_REGISTERS} registers (ignored)")
                return None
            return program
        finally:
            self.ops, self.const_regs, self.cache, self.in_volume = saved

    def _volume_walk(self, node, ctx, acc, visiting, add_node, is_zero):
        """The guard against node cycles and the shader-input walk of both paths (constant and
        program): returns sub(socket, weight), which adds the shader linked into socket
        (weighted; skipped where is_zero(weight)) through add_node."""
        key = (node.as_pointer(), self.ctx_key(ctx))
        if key in visiting:
            raise _Cycle(node.name)
        visiting = visiting | {key}

        def sub(socket, weight):
            src = self.source(socket, ctx)
            if src is None or src[0] == "default" or is_zero(weight):
                return
            _, n, out, nctx = src
            if out.type != 'SHADER':
                self.problem(f"a value linked into the volume shader input of '{node.name}' (ignored)")
                return
            add_node(n, nctx, weight, acc, visiting)
        return sub

    def _acc_add(self, acc, key, v):
        acc[key] = v if acc[key] is None else self.mix("ADD", ONE, acc[key], v)

    def _times(self, color, f):
        """colour (Val) * float (Val)."""
        return self.mix("MULTIPLY", ONE, self.as_color(color), self.as_color(f))

    def _volume_prog_node(self, node, ctx, w, acc, visiting):
        """Adds what volume shader `node` (weight w, a float Val) puts into the medium, as ops."""
        sub = self._volume_walk(node, ctx, acc, visiting, self._volume_prog_node,
                                lambda weight: weight.is_const and weight.const[0] == 0.0)

        def inp(name, kind):
            v = self.input(node, name, ctx, kind)
            return v if v is not None else (ZERO if kind == "float" else const_color((0, 0, 0, 1)))

        def density():  # Cycles: mix weight * max(density, 0) * object_volume_density
            d = self.math("MULTIPLY", self.math("MAXIMUM", inp("Density", "float"), ZERO), w)
            if self.volume_density_scale != 1.0:
                d = self.math("MULTIPLY", d, const_float(self.volume_density_scale))
            return d

        def one_minus(c):  # max(1 - c, 0) for c >= 0 (the mix clamps to [0, 1])
            return self.mix("SUBTRACT", ONE, const_color((1, 1, 1, 1)), c, clamp=True)

        t = node.type
        if t == 'ADD_SHADER':
            sub(node.inputs[0], w)
            sub(node.inputs[1], w)
        elif t == 'MIX_SHADER':
            f = self.math("ADD", inp("Fac", "float"), ZERO, clamp=True)
            sub(node.inputs[1], self.math("MULTIPLY", w, self.math("SUBTRACT", ONE, f)))
            sub(node.inputs[2], self.math("MULTIPLY", w, f))
        elif t == 'VOLUME_ABSORPTION':
            self._acc_add(acc, "sigma_a", self._times(one_minus(inp("Color", "color")), density()))
        elif t == 'VOLUME_SCATTER':
            ss = self._times(inp("Color", "color"), density())
            self._acc_add(acc, "sigma_s", ss)
            kind, names = _phase_of(node)
            acc["scatter"].append((ss, kind, [inp(n, "float") if n in node.inputs else ZERO for n in names]))
        elif t == 'VOLUME_COEFFICIENTS':
            # Cycles 4.5 svm_node_volume_coefficients: the coefficients are sigma_a, sigma_s and
            # the emission per unit length, each times the mix weight (no density); negative
            # values read 0 in the core, as every program's outputs.
            wc = self.as_color(w)
            ss = self.mix("MULTIPLY", ONE, inp("Scatter Coefficients", "color"), wc)
            self._acc_add(acc, "sigma_s", ss)
            kind, names = _phase_of(node)
            acc["scatter"].append((ss, kind, [inp(n, "float") if n in node.inputs else ZERO for n in names]))
            self._acc_add(acc, "sigma_a", self.mix("MULTIPLY", ONE, inp("Absorption Coefficients", "color"), wc))
            em = self.mix("MULTIPLY", ONE, inp("Emission Coefficients", "color"), wc)
            if not self.is_zero(em):
                self._acc_add(acc, "emission", em)
        elif t == 'PRINCIPLED_VOLUME':
            # Cycles' svm_node_principled_volume: scattering colour * density; extinction adds
            # max(1 - colour, 0) max(1 - sqrt(absorption colour), 0) * density; emission
            # strength * colour; blackbody tint * sigma * mix(1, T^4, intensity) * the blackbody
            # colour of T (neither emission scaled by the density).
            c = inp("Color", "color")
            d = density()
            # A volume object's grids named by the node (Cycles: a name it lacks leaves the
            # input as it is; a vector grid read as a float is its components' mean).
            g = self.grid_value(_attr_name(node, "Density Attribute"), "FAC", node)
            if g is not None:
                d = self.math("MAXIMUM", self.math("MULTIPLY", d, g), ZERO)
            g = self.grid_value(_attr_name(node, "Color Attribute"), "COLOR", node)
            if g is not None:
                c = self.mix("MULTIPLY", ONE, c, g)
            ss = self._times(c, d)
            self._acc_add(acc, "sigma_s", ss)
            acc["scatter"].append((ss, "hg", [inp("Anisotropy", "float")]))
            ac = self.value(node.inputs["Absorption Color"], ctx, "color")
            if ac.is_const:
                sq = np.sqrt(np.maximum(np.asarray(ac.const[:3], np.float64), 0.0))
                keep = const_color(tuple(np.maximum(1.0 - sq, 0.0)) + (1.0,))
            else:  # linked (a texture): max(1 - sqrt(max(ac, 0)), 0) per channel, as ops
                roots = [self.math("SQRT", self.math("MAXIMUM", self.separate(ac, i), ZERO), ZERO) for i in range(3)]
                keep = one_minus(self.combine(*roots, "color"))
            absorb = self.mix("MULTIPLY", ONE, one_minus(c), keep)
            self._acc_add(acc, "sigma_a", self._times(absorb, d))
            strength = self.math("MAXIMUM", inp("Emission Strength", "float"), ZERO)
            em = self._times(inp("Emission Color", "color"), self.math("MULTIPLY", strength, w))
            if not self.is_zero(em):
                self._acc_add(acc, "emission", em)
            b = inp("Blackbody Intensity", "float")
            if not (b.is_const and b.const[0] <= 1e-5):
                temp = inp("Temperature", "float")
                g = self.grid_value(_attr_name(node, "Temperature Attribute"), "FAC", node)
                if g is not None:
                    temp = self.math("MULTIPLY", temp, g)
                temp = self.math("MAXIMUM", temp, ZERO)
                t2 = self.math("MULTIPLY", temp, temp)
                t4 = self.math("MULTIPLY", t2, t2)
                # sigma * (1 - b + b T^4)
                mixed = self.math("ADD", self.math("SUBTRACT", ONE, b), self.math("MULTIPLY", b, t4))
                intensity = self.math("MULTIPLY", self.math("MULTIPLY", mixed, const_float(BLACKBODY_SIGMA)), w)
                bb_color = self.fold_or_emit("color", "blackbody", (temp,))
                tint = inp("Blackbody Tint", "color")
                bb = self._times(self.mix("MULTIPLY", ONE, tint, bb_color), intensity)
                self._acc_add(acc, "emission", bb)
        elif t == 'EMISSION':  # an Emission shader in a Volume emits from the whole volume
            em = self._times(inp("Color", "color"), self.math("MULTIPLY", inp("Strength", "float"), w))
            self._acc_add(acc, "emission", em)
        else:
            self.problem(f"volume '{node.name}' ({node.bl_idname}) is not supported (ignored)")

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
        sub = self._volume_walk(node, ctx, acc, visiting, self._volume_node, lambda weight: weight == 0.0)

        def const(name, kind):
            return self._const_or_raise(node, name, ctx, kind)

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
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0]
            kind, names = _phase_of(node)
            params = tuple(float(const(n, "float")) if n in node.inputs else 0.0 for n in names)
            self._add_scatter(acc, w * c * d, kind, params)
        elif t == 'VOLUME_COEFFICIENTS':
            # Cycles 4.5 svm_node_volume_coefficients: sigma_a, sigma_s (of the node's phase)
            # and emission per unit length, each times the mix weight.
            kind, names = _phase_of(node)
            params = tuple(float(const(n, "float")) if n in node.inputs else 0.0 for n in names)
            ss = self._clean(node, "Scatter Coefficients", const("Scatter Coefficients", "color"))
            self._add_scatter(acc, w * ss, kind, params)
            acc["sigma_a"] += w * self._clean(node, "Absorption Coefficients", const("Absorption Coefficients", "color"))
            acc["emission"] += w * self._clean(node, "Emission Coefficients", const("Emission Coefficients", "color"))
        elif t == 'PRINCIPLED_VOLUME':
            # Cycles' svm_node_principled_volume: scattering colour * density; extinction adds
            # (1 - colour)(1 - sqrt(absorption colour)) * density.
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0] * w
            g = float(const("Anisotropy", "float"))
            ac = np.sqrt(self._clean(node, "Absorption Color", const("Absorption Color", "color")))
            self._add_scatter(acc, c * d, "hg", (g,))
            acc["sigma_a"] += np.maximum(1.0 - c, 0.0) * np.maximum(1.0 - ac, 0.0) * d
            strength = float(const("Emission Strength", "float"))
            ec = self._clean(node, "Emission Color", const("Emission Color", "color"))
            if np.isfinite(strength) and strength > 0.0:
                acc["emission"] += w * strength * ec
            if float(const("Blackbody Intensity", "float")) != 0.0:
                raise _Varying()  # blackbody emission: the program's ops compute it
        elif t == 'EMISSION':  # an Emission shader in a Volume emits from the whole volume
            c = self._clean(node, "Color", const("Color", "color"))
            strength = self._clean(node, "Strength", [const("Strength", "float")])[0]
            acc["emission"] += w * strength * c
        else:
            self.problem(f"volume '{node.name}' ({node.bl_idname}) is not supported (ignored)")

    def _add_scatter(self, acc, sigma_s, kind, params):
        """Scattering sigma_s of phase `kind` (parameters: floats; NaN ones 0): summed per phase."""
        params = tuple(float(p) if np.isfinite(p) else 0.0 for p in params)
        if not np.any(sigma_s > 0.0):
            return
        acc["sigma_s"] += sigma_s
        key = (kind, tuple(round(p, 6) for p in params))
        acc["phases"][key] = acc["phases"].get(key, np.zeros(3)) + sigma_s
