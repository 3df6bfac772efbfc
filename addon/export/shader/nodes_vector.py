"""Vector nodes: Vector Math, Mapping, Vector Rotate / Transform, Separate / Combine XYZ,
Bump and Normal Map (a ShaderCompiler mixin)."""

import numpy as np

from .folding import mapping_matrix, vector_math_ops
from .values import ONE, ZERO, const_vector


class VectorNodes:
    """Translators of the vector nodes (ShaderCompiler mixin)."""

    def vector_op(self, op, a, b, c=None):
        """Vector Math on values (floats broadcast), folded when constant."""
        a, b = self.as_vector(a), self.as_vector(b)
        c = const_vector((0, 0, 0)) if c is None else self.as_vector(c)
        return self.fold_or_emit("vector", "vector_math", (a, b, c, ONE), op)

    def vector_math(self, node, out, ctx):
        op = node.operation
        if op not in vector_math_ops():
            return NotImplemented
        by_id = {s.identifier: s for s in node.inputs}
        a, b, c = (self.value(by_id[k], ctx, "vector") or self.socket_default(by_id[k], "vector")
                   for k in ("Vector", "Vector_001", "Vector_002"))
        scale = self.value(by_id["Scale"], ctx, "float")
        value_op = vector_math_ops()[op]["value_out"]
        if (out.identifier == "Value") != value_op:  # the output this operation leaves at 0
            return ZERO if out.identifier == "Value" else const_vector((0, 0, 0))
        kind = "float" if value_op else "vector"
        return self.fold_or_emit(kind, "vector_math", (a, b, c, scale), op)

    def separate_xyz(self, node, out, ctx):
        socket = node.inputs["Vector"]
        v = self.value(socket, ctx, "vector") or self.socket_default(socket, "vector")
        return self.separate(v, "XYZ".index(out.identifier))

    def combine_xyz(self, node, out, ctx):
        return self.combine(*(self.input(node, k, ctx, "float") for k in "XYZ"), "vector")

    def mapping(self, node, ctx):
        vec = self.input(node, "Vector", ctx, "vector")
        vtype = node.vector_type
        params = {}
        for name, default in (("Location", (0, 0, 0)), ("Rotation", (0, 0, 0)),
                              ("Scale", (1, 1, 1))):
            socket = node.inputs.get(name)
            if socket is None or not socket.enabled:
                params[name] = default
            else:
                params[name] = self.const_input(node, name, ctx, "vector").const[:3]
        m = mapping_matrix(vtype, params["Location"], params["Rotation"], params["Scale"])
        if vec.is_const:
            v = m[:, :3].astype(np.float64) @ np.array(vec.const[:3]) + m[:, 3]
            return const_vector(v)
        return self.emit("vector", "mapping", self.reg(vec), m)

    def _vector_or_zero(self, node, identifier, ctx):
        """A vector input found by identifier (also when the node's mode hides it); an
        unlinked hidden-value one reads (0, 0, 0), as Cycles gives these nodes no implicit
        coordinates."""
        socket = next(s for s in node.inputs if s.identifier == identifier)
        v = self.value(socket, ctx, "vector")
        return v if v is not None else const_vector((0, 0, 0))

    def vector_rotate(self, node, out, ctx):
        """Vector Rotate, every type, Invert, every input linkable (always emitted: the core
        evaluates a program that reads no shading point once)."""
        regs = [self.reg(self._vector_or_zero(node, name, ctx)) for name in ("Vector", "Center", "Axis")]
        regs += self._texture_floats(node, ("Angle",), ctx)
        regs.append(self.reg(self._vector_or_zero(node, "Rotation", ctx)))
        return self.emit("vector", "vector_rotate", *regs, node.rotation_type, bool(node.invert))

    def vector_transform(self, node, out, ctx):
        """Vector Transform between world, object and camera space (points, vectors, normals)."""
        v = self.reg(self._vector_or_zero(node, "Vector", ctx))
        return self.emit("vector", "vector_transform", v, node.vector_type, node.convert_from,
                         node.convert_to)

    def bump(self, node, out, ctx):
        """Cycles' Bump: the height at the point and at two offsets Filter Width pixel
        footprints away (Cycles' ray differentials; one filter width per material)."""
        normal = self.normal(node, ctx)
        strength = self.input(node, "Strength", ctx, "float")
        distance = self.input(node, "Distance", ctx, "float")
        height = node.inputs["Height"]
        if self.source(height, ctx) is None or (strength.is_const and strength.const[0] <= 0.0):
            return normal  # nothing to differentiate: the input normal (None: the shading one)
        saved = self.bump_state, self.undisplaced
        # A truly displaced material's Bump ('BOTH'): its heights on the undisplaced surface.
        both = self.displacement_method == 'BOTH'
        heights = []
        try:
            self.undisplaced = both
            for state in (0, 1, 2):
                self.bump_state = state
                heights.append(self.value(height, ctx, "float"))
        finally:
            self.bump_state, self.undisplaced = saved
        if all(h.is_const for h in heights):
            return normal  # a constant height has no slope
        width_socket = node.inputs.get("Filter Width")
        width = 0.1 if width_socket is None else self.const_input(node, "Filter Width", ctx, "float").const[0]
        first = self.cache.setdefault("bump_filter_width", width)
        if first != width:
            self.problem(f"'{node.name}': Filter Width {width:g} differs from another Bump's "
                         f"{first:g} in the material (that one is used)")
        return self.emit("vector", "bump", *(self.reg(h) for h in heights), self.reg(strength),
                         self.reg(distance), None if normal is None else self.reg(normal),
                         bool(node.invert), max(0.0, float(width)), *((True,) if both else ()))

    def displacement(self, node, out, ctx):
        """Cycles' svm_node_displacement: the Normal (unlinked: the shading normal) times
        (Height - Midlevel) * Scale; in object space through the instance's transform (the
        normal to object space as a normal, the offset back as a vector: scaled objects
        displace by their scale, as in Cycles)."""
        amount = self.math("MULTIPLY", self.math("SUBTRACT", self.input(node, "Height", ctx, "float"),
                                                 self.input(node, "Midlevel", ctx, "float")),
                           self.input(node, "Scale", ctx, "float"))
        normal = self.normal(node, ctx)
        if normal is None:
            normal = self.emit("vector", "normal")
        return self._displace(normal, amount, node.space == 'OBJECT', "NORMAL")

    def vector_displacement(self, node, out, ctx):
        """Cycles' svm_node_vector_displacement: (Vector - Midlevel) * Scale in world space, object
        space (through the instance's transform) or tangent space (the active render UV map's
        MikkTSpace tangent, the normal and the bitangent as x, y, z)."""
        mid = self.as_vector(self.input(node, "Midlevel", ctx, "float"))
        v = self.vector_op("SUBTRACT", self.input(node, "Vector", ctx, "vector"), mid)
        scale = self.input(node, "Scale", ctx, "float")
        if node.space == 'TANGENT':  # the active render UV map's tangents (Cycles' default)
            k = self.uv("", f"'{node.name}'")
            zero = const_vector((0, 0, 0))
            scaled = self.fold_or_emit("vector", "vector_math", (self.as_vector(v), zero, zero, scale), "SCALE")
            return self.emit("vector", "tangent_displacement", self.reg(scaled), k)
        return self._displace(v, scale, node.space != 'WORLD', "VECTOR")

    def _displace(self, v, amount, object_space, kind):
        zero = const_vector((0, 0, 0))
        if object_space:
            v = self.emit("vector", "vector_transform", self.reg(v), kind, 'WORLD', 'OBJECT') \
                if kind == "NORMAL" else v
        d = self.fold_or_emit("vector", "vector_math", (self.as_vector(v), zero, zero, amount), "SCALE")
        if object_space:
            d = self.emit("vector", "vector_transform", self.reg(d), 'VECTOR', 'OBJECT', 'WORLD')
        return d

    def true_displacement(self, socket):
        """The program of the material output's Displacement for true displacement (Cycles'
        'DISPLACEMENT' and 'BOTH' methods): its value ops with their own registers and cache,
        ending in a 'displacement' op whose offset (world space) the core adds to each vertex
        before the BVH is built. None where the displacement is constant zero."""
        from .registers import allocate_registers, eliminate_dead_code
        saved = self.ops, self.const_regs, self.cache, self.bump_state
        self.ops, self.const_regs, self.cache, self.bump_state = [], {}, {}, 0
        try:
            v = self.value(socket, (), "vector")
            if v is None or self.is_zero(v):
                return None
            self.ops.append(("closure", "displacement", None, {"offset": self.reg(self.as_vector(v))}))
            program = allocate_registers(eliminate_dead_code(self.ops))
        finally:
            self.ops, self.const_regs, self.cache, self.bump_state = saved
        if program is None:
            self.problem("the displacement needs too many registers (not displaced)")
        return program

    def bump_from_displacement(self, socket, method):
        """Cycles' bump_from_displacement for the material output's Displacement: the offset's
        component along the normal at the point and at the Bump node's two offsets, a Bump of
        Strength 1 and Distance 1 (Filter Width 0.1) whose normal then replaces the shading
        normal for everything after it (Cycles' Set Normal). Cycles duplicates the subgraph,
        so its reads of the normal are the unbumped one: compiled first, with a cache of its
        own."""
        saved, self.cache = self.cache, {}
        self.undisplaced = method == 'BOTH'  # (its vertices moved: the bump reads the surface before)
        heights = []
        try:
            normal = self.emit("vector", "normal")
            for state in (0, 1, 2):
                self.bump_state = state
                v = self.value(socket, (), "vector")
                if v is None:
                    return
                heights.append(self.fold_or_emit("float", "vector_math",
                                                 (self.as_vector(v), normal, const_vector((0, 0, 0)), ONE),
                                                 "DOT_PRODUCT"))
        finally:
            self.bump_state = 0
            self.undisplaced = False
            width = self.cache.get("bump_filter_width")
            self.cache = saved
            if width is not None:
                self.cache["bump_filter_width"] = width
        if all(h.is_const for h in heights):
            return
        first = self.cache.setdefault("bump_filter_width", 0.1)
        if first != 0.1:
            self.problem(f"the displacement's bump uses Filter Width 0.1, not another Bump's {first:g}")
        bump = self.emit("vector", "bump", *(self.reg(h) for h in heights), self.reg(ONE), self.reg(ONE),
                         None, False, 0.1, *((True,) if method == 'BOTH' else ()))
        self.ops.append(("set_normal", self.new_reg(), self.reg(bump)))

    def normal_node(self, node, out, ctx):
        """The Normal node (Cycles' svm_node_normal): its direction, normalised, and the dot
        product of that with its normalised Normal input."""
        d = np.asarray(node.outputs["Normal"].default_value[:3], np.float64)
        length = float(np.linalg.norm(d))
        direction = const_vector(tuple(d / length) if length > 0.0 else (0.0, 0.0, 0.0))
        if out.identifier == "Normal":
            return direction
        n = self.vector_op("NORMALIZE", self.input(node, "Normal", ctx, "vector"), ZERO)
        by = self.fold_or_emit("float", "vector_math", (direction, n, const_vector((0, 0, 0)), ONE),
                               "DOT_PRODUCT")
        return by

    def normal_map(self, node, ctx):
        """Normal Map in every space of Cycles: tangent (a UV map's tangents), object (turned
        by the hit instance's transform), world, and their Blender variants."""
        what = f"'{node.name}'"
        color = self.input(node, "Color", ctx, "color")
        strength = self.input(node, "Strength", ctx, "float")
        if strength.is_const and strength.const[0] == 0.0:
            return None
        if node.space != 'TANGENT':
            return self.emit("vector", "normal_map", self.reg(color), self.reg(strength), 0,
                             node.space)
        k = self.uv(node.uv_map, what)
        return self.emit("vector", "normal_map", self.reg(color), self.reg(strength), k)


# Handlers of ShaderCompiler._VALUE_NODES (Mapping and Normal Map are eval_value_node's).
VALUE_NODES = {
    'BUMP': VectorNodes.bump, 'SEPXYZ': VectorNodes.separate_xyz,
    'COMBXYZ': VectorNodes.combine_xyz, 'VECT_MATH': VectorNodes.vector_math,
    'VECTOR_ROTATE': VectorNodes.vector_rotate, 'VECT_TRANSFORM': VectorNodes.vector_transform,
    'DISPLACEMENT': VectorNodes.displacement, 'VECTOR_DISPLACEMENT': VectorNodes.vector_displacement,
    'NORMAL': VectorNodes.normal_node,
}
