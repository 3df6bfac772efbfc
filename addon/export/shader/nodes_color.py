"""Colour nodes and converters: ramps and curves, hue / saturation, gamma, brightness /
contrast, separating and combining colours, Blackbody and Wavelength (a ShaderCompiler
mixin)."""

import numpy as np

from .folding import RAMP_TABLE_SIZE, fold
from .values import Val, const_color, const_float, const_vector


class ColorNodes:
    """Translators of the colour nodes (ShaderCompiler mixin)."""

    def ramp(self, src, table, interpolate, extrapolate=False, lo=0.0, hi=1.0, channels=False,
             kind="color"):
        args = (np.ascontiguousarray(table, np.float32), bool(interpolate), bool(extrapolate),
                float(lo), float(hi), bool(channels))
        if src.is_const:  # the core's own lookup, in its float arithmetic
            return fold(kind, "ramp", [src], *args)
        return self.emit(kind, "ramp", self.reg(src), *args)

    def color_ramp(self, node, out, ctx):
        """Cycles bakes the ramp (any interpolation and colour mode) into a 256-entry table."""
        fac = self.input(node, "Fac", ctx, "float")
        ramp = node.color_ramp
        table = np.array([tuple(ramp.evaluate(i / (RAMP_TABLE_SIZE - 1)))
                          for i in range(RAMP_TABLE_SIZE)], np.float64)
        interpolate = ramp.interpolation != 'CONSTANT'
        if out.identifier == "Alpha":
            return self.ramp(fac, np.repeat(table[:, 3:4], 4, axis=1), interpolate, kind="float")
        return self.ramp(fac, table, interpolate)

    def rgb_curves(self, node, out, ctx):
        """Cycles' curvemapping_color_to_array: the combined curve then each channel's, over
        the range of all curves' points, 256 entries."""
        fac = self.input(node, "Fac", ctx, "float")
        color = self.input(node, "Color", ctx, "color")
        mapping = node.mapping
        mapping.initialize()
        curves = list(mapping.curves)
        # The range is over all four curves (Cycles' curvemapping_minmax(mapping, 4, ...)).
        _, lo, hi = self._curve_table(mapping, curves[:4])
        table = np.ones((RAMP_TABLE_SIZE, 4))
        for i in range(RAMP_TABLE_SIZE):
            t = lo + i / (RAMP_TABLE_SIZE - 1) * (hi - lo)
            combined = mapping.evaluate(curves[3], t)
            table[i, :3] = [mapping.evaluate(curves[c], combined) for c in range(3)]
        curved = self.ramp(color, table, True, mapping.extend == 'EXTRAPOLATED', lo, hi,
                           channels=True)
        return self._curve_mix(fac, color, curved, "color")

    def _curve_table(self, mapping, curves, combined=None):
        """Cycles' curvemapping_*_to_array: `curves` evaluated (after the combined curve, if
        any) at RAMP_TABLE_SIZE points over curvemapping_minmax's range, and that range."""
        los = [c.points[0].location[0] for c in curves if len(c.points)]
        his = [c.points[-1].location[0] for c in curves if len(c.points)]
        lo, hi = (min(los), max(his)) if los else (0.0, 1.0)
        table = np.ones((RAMP_TABLE_SIZE, 4))
        for i in range(RAMP_TABLE_SIZE):
            t = lo + i / (RAMP_TABLE_SIZE - 1) * (hi - lo)
            if combined is not None:
                t = mapping.evaluate(combined, t)
            table[i, :len(curves[:3])] = [mapping.evaluate(c, t) for c in curves[:3]]
        return table, lo, hi

    def _curve_mix(self, fac, v, curved, kind):
        """Cycles' svm_node_curves blend, v + fac (curved - v), fac not clamped."""
        if fac.is_const and 0.0 <= fac.const[0] <= 1.0:
            return self.mix("MIX", fac, v, curved, kind=kind)
        delta = self.vector_op("SUBTRACT", curved, v)
        out = self.vector_op("MULTIPLY_ADD", delta, fac, v)
        return self.convert(out, kind)

    def vector_curves(self, node, out, ctx):
        """Vector Curves: Cycles' VectorCurvesNode, the X, Y and Z curves baked over their
        common range, each component through its own curve, blended by Fac."""
        fac = self.input(node, "Fac", ctx, "float")
        v = self.input(node, "Vector", ctx, "vector")
        mapping = node.mapping
        mapping.initialize()
        curves = list(mapping.curves)[:3]
        table, lo, hi = self._curve_table(mapping, curves)
        curved = self.ramp(v, table, True, mapping.extend == 'EXTRAPOLATED', lo, hi, channels=True,
                           kind="vector")
        return self._curve_mix(fac, v, curved, "vector")

    def float_curve(self, node, out, ctx):
        """Float Curve: Cycles' FloatCurveNode (svm_node_float_curve), the curve baked over its
        range, blended with the value by Factor."""
        fac = self.input(node, "Factor", ctx, "float")
        v = self.input(node, "Value", ctx, "float")
        mapping = node.mapping
        mapping.initialize()
        curve = mapping.curves[0]
        table, lo, hi = self._curve_table(mapping, [curve])
        table[:, 1:3] = table[:, :1]
        curved = self.ramp(v, table, True, mapping.extend == 'EXTRAPOLATED', lo, hi, kind="float")
        if fac.is_const and fac.const[0] == 1.0:
            return curved
        # (1 - fac) v + fac curved, fac not clamped
        return self.math("MULTIPLY_ADD", self.math("SUBTRACT", curved, v), fac, c=v)

    def color_space(self, v, conversion, kind):
        if v.is_const:
            c = self.fold_or_emit("color", "color_space", (v,), conversion)
            return Val(kind, c.const[:3] + (v.const[3],))
        return self.emit(kind, "color_space", self.reg(v), conversion)

    def separate(self, v, axis):
        if v.is_const:
            return const_float(v.const[axis])
        return self.emit("float", "separate", self.reg(v), axis)

    def combine(self, a, b, c, kind):
        if a.is_const and b.is_const and c.is_const:
            xyz = (a.const[0], b.const[0], c.const[0])
            return const_color(xyz + (1.0,)) if kind == "color" else const_vector(xyz)
        return self.emit(kind, "combine", self.reg(a), self.reg(b), self.reg(c), kind == "color")

    def separate_color(self, node, out, ctx):
        color = self.input(node, "Color" if "Color" in node.inputs else "Image", ctx, "color")
        mode = getattr(node, "mode", 'HSV' if node.type == 'SEPHSV' else 'RGB')
        if mode in ('HSV', 'HSL'):
            color = self.color_space(color, f"RGB_TO_{mode}", "color")
        axis = [o.identifier for o in node.outputs].index(out.identifier)
        return self.separate(color, axis)

    def combine_color(self, node, out, ctx):
        ins = [self.value(s, ctx, "float") for s in list(node.inputs)[:3]]
        mode = getattr(node, "mode", 'HSV' if node.type == 'COMBHSV' else 'RGB')
        color = self.combine(*ins, "color")
        if mode in ('HSV', 'HSL'):
            color = self.color_space(color, f"{mode}_TO_RGB", "color")
        return color

    def hue_saturation(self, node, out, ctx):
        ins = [self.input(node, "Color", ctx, "color")] + [
            self.input(node, k, ctx, "float") for k in ("Hue", "Saturation", "Value", "Fac")]
        return self.fold_or_emit("color", "hsv", ins, alpha=1.0)

    def gamma(self, node, out, ctx):
        c = self.input(node, "Color", ctx, "color")
        g = self.input(node, "Gamma", ctx, "float")
        return self.fold_or_emit("color", "gamma", (c, g), alpha=1.0)

    def bright_contrast(self, node, out, ctx):
        c = self.input(node, "Color", ctx, "color")
        bright = self.input(node, "Bright", ctx, "float")
        contrast = self.input(node, "Contrast", ctx, "float")
        if c.is_const and bright.is_const and contrast.is_const:
            a, b = 1.0 + contrast.const[0], bright.const[0] - contrast.const[0] * 0.5
            return const_color(tuple(max(a * x + b, 0.0) for x in c.const[:3]) + (1.0,))
        return self.emit("color", "bright_contrast", self.reg(c), self.reg(bright),
                         self.reg(contrast))

    def blackbody(self, node, out, ctx):
        (t,) = self._texture_floats(node, ("Temperature",), ctx)
        return self.emit("color", "blackbody", t)

    def wavelength(self, node, out, ctx):
        (w,) = self._texture_floats(node, ("Wavelength",), ctx)
        return self.emit("color", "wavelength", w)


# Handlers of ShaderCompiler._VALUE_NODES (node type -> function of compiler, node, output
# socket, group context).
VALUE_NODES = {
    'VALTORGB': ColorNodes.color_ramp, 'CURVE_RGB': ColorNodes.rgb_curves,
    'CURVE_VEC': ColorNodes.vector_curves, 'CURVE_FLOAT': ColorNodes.float_curve,
    'SEPARATE_COLOR': ColorNodes.separate_color, 'SEPRGB': ColorNodes.separate_color,
    'SEPHSV': ColorNodes.separate_color, 'COMBINE_COLOR': ColorNodes.combine_color,
    'COMBRGB': ColorNodes.combine_color, 'COMBHSV': ColorNodes.combine_color,
    'HUE_SAT': ColorNodes.hue_saturation, 'GAMMA': ColorNodes.gamma,
    'BRIGHTCONTRAST': ColorNodes.bright_contrast, 'BLACKBODY': ColorNodes.blackbody,
    'WAVELENGTH': ColorNodes.wavelength,
}
