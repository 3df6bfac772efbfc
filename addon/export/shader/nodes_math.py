"""Math, Map Range, Clamp and the Mix nodes (a ShaderCompiler mixin)."""

from .folding import math_ops, mix_blends
from .values import ZERO, Val, const_float


class MathNodes:
    """Translators of the Math, Map Range, Clamp and Mix nodes (ShaderCompiler mixin)."""

    def math_node(self, node, ctx):
        op = node.operation
        a = self.value(node.inputs[0], ctx, "float")
        b = self.value(node.inputs[1], ctx, "float")
        clamp = node.use_clamp
        if op in math_ops():
            c = self.value(node.inputs[2], ctx, "float") if math_ops()[op]["operands"] == 3 else None
            return self.math(op, a, b, clamp, c)
        self.problem(f"'{node.name}': math operation {op.replace('_', ' ').title()} is not "
                     "supported (its first value is used)")
        return self.math("ADD", a, ZERO, clamp)

    def clamp_node(self, node, out, ctx):
        v, lo, hi = (self.input(node, k, ctx, "float") for k in ("Value", "Min", "Max"))
        return self.fold_or_emit("float", "clamp", (v, lo, hi), node.clamp_type)

    def map_range(self, node, out, ctx):
        by_id = {s.identifier: s for s in node.inputs}
        mode = node.interpolation_type
        if node.data_type == 'FLOAT_VECTOR':
            if out.identifier != "Vector":
                return ZERO
            ins = [self.value(by_id[k], ctx, "vector") or self.socket_default(by_id[k], "vector")
                   for k in ("Vector", "From_Min_FLOAT3", "From_Max_FLOAT3", "To_Min_FLOAT3",
                             "To_Max_FLOAT3", "Steps_FLOAT3")]
            return self.fold_or_emit("vector", "map_range_vector", ins, mode, bool(node.clamp))
        if node.data_type != 'FLOAT':
            return NotImplemented
        ins = [self.value(by_id[k], ctx, "float")
               for k in ("Value", "From Min", "From Max", "To Min", "To Max", "Steps")]
        mode = node.interpolation_type
        return self.fold_or_emit("float", "map_range", ins, mode, bool(node.clamp))

    def mix_color(self, node, blend, fac, a, b, clamp):
        if blend not in mix_blends():
            self.problem(f"'{node.name}': blend mode {blend.replace('_', ' ').title()} is not "
                         "supported (Mix)")
            blend = "MIX"
        return self.mix(blend, fac, a, b, clamp)

    def mix_node(self, node, oid, ctx):
        """Blender's Mix node; its sockets share names, so they are found by identifier."""
        by_id = {s.identifier: s for s in node.inputs}
        dtype = node.data_type
        if dtype == 'RGBA':
            fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            return self.mix_color(node, node.blend_type, fac,
                                  self.value(by_id["A_Color"], ctx, "color"),
                                  self.value(by_id["B_Color"], ctx, "color"),
                                  node.clamp_result)
        if dtype == 'FLOAT':
            fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            return self.mix("MIX", fac, self.value(by_id["A_Float"], ctx, "float"),
                            self.value(by_id["B_Float"], ctx, "float"), kind="float")
        if dtype == 'VECTOR':
            if node.factor_mode == 'NON_UNIFORM':
                self.problem(f"'{node.name}': non-uniform factor is not supported (its X is "
                             "used)")
                fac = self.value(by_id["Factor_Vector"], ctx, "vector")
                fac = const_float(fac.const[0]) if fac.is_const else Val("float", reg=fac.reg)
            else:
                fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            a = self.value(by_id["A_Vector"], ctx, "vector")
            b = self.value(by_id["B_Vector"], ctx, "vector")
            return self.mix("MIX", fac, a, b, kind="vector")
        return NotImplemented

    def _note_unclamped_factor(self, node, fac):
        if not node.clamp_factor and not (fac.is_const and 0.0 <= fac.const[0] <= 1.0):
            self.problem(f"'{node.name}': an unclamped factor is clamped to [0, 1]")


# Handlers of ShaderCompiler._VALUE_NODES (the Math and Mix nodes are eval_value_node's).
VALUE_NODES = {
    'CLAMP': MathNodes.clamp_node, 'MAP_RANGE': MathNodes.map_range,
}
