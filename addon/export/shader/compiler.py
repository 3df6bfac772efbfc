"""The compiler of one material: walks the node tree from its output, emitting register
instructions for value nodes (constant sub-graphs folded) and weighted closures for shader
nodes; the node translators are mixins grouped by family (nodes_*.py, volume.py)."""

from dataclasses import dataclass, field

from . import nodes_color, nodes_input, nodes_math, nodes_textures, nodes_vector, tex_patterns
from .folding import fold, math_ops
from .graph import GraphWalk, _Cycle
from .nodes_closures import ClosureNodes
from .nodes_color import ColorNodes
from .nodes_input import InputNodes
from .nodes_math import MathNodes
from .nodes_textures import TextureNodes
from .nodes_vector import VectorNodes
from .registers import MAX_REGISTERS, allocate_registers, eliminate_dead_code
from .values import GREY, LUMA, ONE, ZERO, Val, const_color, const_float, const_vector
from .volume import VolumeShaders


@dataclass
class CompiledShader:
    program: list  # tuples of docs/core_api.md; image operands index ImageTable.images
    volume_absorption: tuple = None  # ((r, g, b), density) or None
    volume: dict = None  # the homogeneous medium (sigma_a, sigma_s, g, emission) or None
    # k -> UV map name this material reads, or for attribute sets (numbered with the uv sets)
    # ("attr", name) (the Attribute node) / ("color", name) (Color Attribute; "" = the render one).
    uv_sets: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)  # what was approximated/unsupported
    # True displacement ('DISPLACEMENT' / 'BOTH'): value ops ending in ('closure',
    # 'displacement', None, {'offset': r}), the world offset at a vertex; None: none.
    displacement: list = None
    displacement_method: str = 'BUMP'


class ShaderCompiler(GraphWalk, InputNodes, MathNodes, ColorNodes, VectorNodes, TextureNodes,
                     ClosureNodes, VolumeShaders):
    """Compiles one material's node tree. Use `compile_material`."""

    def __init__(self, images, uv_sets, material_index=0, view_layer_ids=(), depsgraph=None,
                 volume_grids=None, scene_grids=None):
        self.images = images
        # The export's list of core grids (Point Density textures append theirs; a grid's id
        # is its index), or None where there is no scene export (previews of one material).
        self.scene_grids = scene_grids
        self.scene_grid_cache = {}
        self.in_volume = False  # compiling the Volume (Point Density reads 0 elsewhere, as Cycles)
        # A volume object's grids, {name: (core grid id, channels)}, or None (any other object):
        # attributes then read grids (nodes_input.grid_value) and the surface is a pass-through.
        self.volume_grids = volume_grids
        self.volume_interpolation = 'LINEAR'
        # Cycles' object_volume_density of a volume object (1 / its scale, Space 'OBJECT'):
        # multiplies the volume shaders' densities, not their emission.
        self.volume_density_scale = 1.0
        self.uv_sets = uv_sets
        self.material_index = material_index  # the material's pass index (Object Info)
        # Where the Attribute node's View Layer attributes are looked up, in order (Blender: the
        # view layer, its scene, the scene's world).
        self.view_layer_ids = tuple(view_layer_ids)
        self.depsgraph = depsgraph  # where other objects' evaluated transforms are read
        self.ops = []  # with virtual registers
        self.nreg = 0
        self.const_regs = {}  # const tuple -> virtual register
        self.cache = {}  # (node ptr, output identifier, ctx key) -> Val
        self.visiting = set()
        self.problems = []
        self.uv_used = {}
        self._links = {}  # tree pointer -> {to_socket pointer: link}
        # Where reads of the shading point happen: 0 the point, 1 / 2 the Bump node's offsets
        # (its Height sub-graph is compiled once per offset, as Cycles duplicates it).
        self.bump_state = 0
        # True displacement: the material's method once its vertex program exists ('BOTH':
        # bump heights read the undisplaced surface, `undisplaced` while they compile).
        self.displacement_method = 'BUMP'
        self.undisplaced = False

    # -------------------------------------------------- problems

    def problem(self, msg):
        if msg not in self.problems:
            self.problems.append(msg)

    # -------------------------------------------------- registers

    def new_reg(self):
        self.nreg += 1
        return self.nreg - 1

    def reg(self, val):
        """The register holding `val` (constants are materialised once)."""
        if not val.is_const:
            return val.reg
        r = self.const_regs.get(val.const)
        if r is None:
            r = self.const_regs[val.const] = self.new_reg()
            self.ops.append(("const", r, val.const))
        return r

    def emit(self, kind, *args):
        r = self.new_reg()
        self.ops.append((args[0], r) + tuple(args[1:]))
        return Val(kind, reg=r)

    def fold_or_emit(self, kind, name, vals, *tail, alpha=None):
        """Op `name` of operands `vals` then literals `tail`: folded by the core where every
        operand is a constant, else emitted."""
        if all(v.is_const for v in vals):
            return fold(kind, name, vals, *tail, alpha=alpha)
        return self.emit(kind, name, *(self.reg(v) for v in vals), *tail)

    # -------------------------------------------------- conversions

    def as_float(self, v, what=""):
        if v.kind == "float":
            return v
        if v.is_const:
            if v.kind == "vector":  # Blender: the average of the components
                return const_float(sum(v.const[:3]) / 3.0)
            return const_float(sum(c * w for c, w in zip(v.const[:3], LUMA)))
        if v.kind == "vector":
            self.problem(f"vector-to-value conversion{what} approximated by luminance")
        return self.emit("float", "rgb_to_bw", self.reg(v))

    def as_color(self, v):
        if v.kind == "color":
            return v
        if v.is_const:
            c = v.const
            return Val("color", (c[0], c[1], c[2], 1.0))
        return Val("color", reg=v.reg)  # floats are broadcast, vectors reinterpreted

    def as_vector(self, v):
        if v.kind == "vector":
            return v
        if v.is_const:
            c = v.const
            return Val("vector", (c[0], c[1], c[2], 0.0))
        return Val("vector", reg=v.reg)

    def convert(self, v, kind, what=""):
        if kind == "float":
            return self.as_float(v, what)
        if kind == "vector":
            return self.as_vector(v)
        return self.as_color(v)

    # -------------------------------------------------- arithmetic (folded when constant)

    def math(self, op, a, b, clamp=False, c=None):
        a, b = self.as_float(a), self.as_float(b)
        c = ZERO if c is None else self.as_float(c)
        if math_ops()[op]["operands"] == 3:
            return self.fold_or_emit("float", "math3", (a, b, c), op, bool(clamp))
        return self.fold_or_emit("float", "math", (a, b), op, bool(clamp))

    def mix(self, blend, fac, a, b, clamp=False, kind="color"):
        """The core's mix: fac (clamped to [0, 1]) in .x, per-channel blend of a and b."""
        fac = self.as_float(fac)
        a, b = self.convert(a, kind), self.convert(b, kind)
        if fac.is_const and a.is_const and b.is_const:
            v = fold(kind, "mix", (fac, a, b), blend, bool(clamp), alpha=a.const[3])
            return Val(kind, v.const[:3] + (a.const[3],))
        if fac.is_const and blend == "MIX" and not clamp:
            f = min(max(fac.const[0], 0.0), 1.0)
            if f == 0.0:
                return a
            if f == 1.0:
                return b
        return self.emit(kind, "mix", self.reg(fac), self.reg(a), self.reg(b), blend, bool(clamp))

    def scale(self, weight, s):
        """weight (colour) * s (float or colour), either None meaning 1."""
        if weight is None:
            return s
        if s is None:
            return weight
        if weight.is_const and all(x == 1.0 for x in weight.const[:3]):
            return self.as_color(s)
        if s.is_const and all(x == 1.0 for x in s.const[:3]):
            return weight
        return self.mix("MULTIPLY", ONE, weight, s)

    @staticmethod
    def is_zero(v):
        return v is not None and v.is_const and all(x == 0.0 for x in v.const[:3])

    # -------------------------------------------------- values of inputs

    def socket_default(self, socket, kind):
        """Val of an unconnected socket's own value, converted to `kind`."""
        dv = getattr(socket, "default_value", None)
        if dv is None:
            return {"float": ZERO, "color": const_color((0, 0, 0, 1)),
                    "vector": const_vector((0, 0, 0))}[kind]
        if isinstance(dv, (bool, int, float)):
            v = const_float(dv)
        else:
            vals = tuple(dv)
            v = const_color(vals) if len(vals) == 4 else const_vector(
                (vals + (0.0, 0.0, 0.0))[:3])
            if socket.type == 'RGBA':
                v = const_color(vals)
        return self.convert(v, kind)

    def value(self, socket, ctx, kind):
        """Val of input `socket` (linked or not) as `kind`. Returns None for an unconnected
        socket whose default is "implicit" (hidden-value vectors: Normal, image Vector...)."""
        src = self.source(socket, ctx)
        if src is None:
            if getattr(socket, "hide_value", False) and socket.type == 'VECTOR':
                return None
            return self.socket_default(socket, kind)
        if src[0] == "default":
            return self.socket_default(src[1], kind)
        _, node, out, nctx = src
        if out.type == 'SHADER':
            self.problem(f"shader output of '{node.name}' linked to a value input "
                         f"({socket.name}) ignored")
            return self.socket_default(socket, kind)
        v = self.node_output(node, out, nctx, socket, kind)
        if v is None:  # an implicit value (e.g. the shading normal)
            if getattr(socket, "hide_value", False) and socket.type == 'VECTOR':
                return None
            return self.socket_default(socket, kind)
        return self.convert(v, kind, f" into {socket.name}")

    def input(self, node, name, ctx, kind):
        return self.value(node.inputs[name], ctx, kind)

    def const_input(self, node, name, ctx, kind):
        """A constant input value (used where the core takes constants): a linked input is a
        problem, its socket's own value is used."""
        socket = node.inputs[name]
        v = self.value(socket, ctx, kind)
        if v is not None and v.is_const:
            return v
        self.problem(f"linked input {name} of '{node.name}' is not supported (its value is used)")
        return self.socket_default(socket, kind)

    def node_output(self, node, out, ctx, consumer, kind):
        key = (node.as_pointer(), out.identifier, self.ctx_key(ctx), self.bump_state)
        if key in self.cache:
            return self.cache[key]
        if key in self.visiting:
            raise _Cycle(node.name)
        self.visiting.add(key)
        try:
            v = self.eval_value_node(node, out, ctx)
        finally:
            self.visiting.discard(key)
        if v is NotImplemented:
            return self._fallback_value(node, ctx, consumer, kind)
        self.cache[key] = v
        return v

    def _fallback_value(self, node, ctx, consumer, kind):
        """An unsupported value node: its own Color input when it has one (linked or not),
        else the consumer socket's own value (None, the implicit value, for hidden vectors)."""
        color = node.inputs.get("Color")
        what = f"'{node.name}' ({node.bl_idname}) is not supported"
        if color is not None and kind == "color":
            self.problem(f"{what} (its Color input is used)")
            v = self.value(color, ctx, "color")
            return v if v is not None else self.socket_default(color, "color")
        if getattr(consumer, "hide_value", False) and consumer.type == 'VECTOR':
            self.problem(f"{what} (ignored)")
            return None
        self.problem(f"{what} (the value of {consumer.name} is used)")
        return self.socket_default(consumer, kind)

    # -------------------------------------------------- value nodes

    def eval_value_node(self, node, out, ctx):
        t = node.type
        oid = out.identifier
        if t == 'RGB':
            return const_color(out.default_value)
        if t == 'VALUE':
            return const_float(out.default_value)
        if t == 'TEX_IMAGE':
            return self.image_texture(node, out, ctx)
        if t == 'TEX_COORD':
            return self.tex_coord(node, oid)
        if t == 'UVMAP':
            if node.from_instancer:  # Cycles: the instance's dupli uv, whatever the map
                return self.instancer_coords(node, "UV")
            return self.uv_value(node.uv_map, f"'{node.name}'")
        if t == 'NEW_GEOMETRY':
            if oid == "Position":
                return self.position()
            if oid == "Normal":
                return self.emit("vector", "normal")
            if oid == "Tangent":  # Cycles: radial around the object's Z axis
                return self.emit("vector", "tangent", "Z", 0)
            if oid == "Pointiness":  # per vertex, computed at export as Cycles does
                return self.attribute_value("pointiness", "", "ALPHA", f"'{node.name}'")
            if oid == "Random Per Island":  # per triangle, computed at export as Cycles does
                return self.attribute_value("island", "", "ALPHA", f"'{node.name}'")
            which = self._GEOMETRY.get(oid)
            if which is not None:
                return self.emit("float" if oid == "Backfacing" else "vector", "geometry", which)
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO if out.type == 'VALUE' else const_vector((0, 0, 0))
        if t == 'MAPPING':
            return self.mapping(node, ctx)
        if t == 'MIX':
            return self.mix_node(node, oid, ctx)
        if t == 'MIX_RGB':
            return self.mix_color(node, node.blend_type, self.input(node, "Fac", ctx, "float"),
                                  self.input(node, "Color1", ctx, "color"),
                                  self.input(node, "Color2", ctx, "color"), node.use_clamp)
        if t == 'MATH':
            return self.math_node(node, ctx)
        if t == 'RGBTOBW':
            return self.as_float(self.input(node, "Color", ctx, "color"))
        if t == 'INVERT':
            fac = self.input(node, "Fac", ctx, "float")
            c = self.input(node, "Color", ctx, "color")
            inverted = self.mix("SUBTRACT", ONE, const_color((1, 1, 1, 1)), c)
            return self.mix("MIX", fac, c, inverted)
        if t == 'NORMAL_MAP':
            return self.normal_map(node, ctx)
        handler = self._VALUE_NODES.get(t)
        if handler is not None:
            return handler(self, node, out, ctx)
        return NotImplemented

    # Value node types beyond eval_value_node's own: each family's handlers.
    _VALUE_NODES = {**nodes_input.VALUE_NODES, **nodes_math.VALUE_NODES, **nodes_color.VALUE_NODES,
                    **nodes_vector.VALUE_NODES, **nodes_textures.VALUE_NODES,
                    **tex_patterns.NODES}

    # -------------------------------------------------- entry

    def compile(self, output, name, displacement_method='BUMP'):
        """CompiledShader for a material output node (displacement_method: the material's)."""
        volume = None
        if self.volume_grids is not None:  # a volume object: its Volume only
            try:
                volume = self.volume(output.inputs["Volume"], name)
            except _Cycle as e:
                self.problem(f"node cycle through '{e}' in the volume (ignored)")
            self._reset()
            self.closure("transparent", None, color=const_color((1.0, 1.0, 1.0)))
            program = allocate_registers(eliminate_dead_code(self.ops))
            medium = volume if isinstance(volume, (dict, list)) else None
            if isinstance(volume, tuple):  # a lone constant Volume Absorption: as a medium
                (c, d) = volume
                medium = {"sigma_a": tuple(max(1.0 - min(float(x), 1.0), 0.0) * max(float(d), 0.0) for x in c),
                          "sigma_s": (0.0, 0.0, 0.0), "emission": (0.0, 0.0, 0.0), "g": 0.0}
            return CompiledShader(program, None, medium, dict(self.uv_used), list(self.problems))
        disp = output.inputs.get("Displacement")
        displacement = None
        if disp is not None and self.link_into(disp) is not None:
            try:
                if displacement_method in ('DISPLACEMENT', 'BOTH'):
                    displacement = self.true_displacement(disp)
                    # (its Bump nodes then read the undisplaced surface, as Cycles')
                    self.displacement_method = displacement_method if displacement else 'BUMP'

                if displacement_method != 'DISPLACEMENT':  # 'BOTH': the bump as well (Cycles)
                    self.bump_from_displacement(disp, displacement_method)
            except _Cycle as e:
                self.problem(f"node cycle through '{e}' in the displacement (ignored)")
        try:
            self.shader_input(output.inputs["Surface"], (), None)
        except _Cycle as e:
            self.problem(f"node cycle through '{e}' (grey diffuse)")
            self._reset()
            self.closure("diffuse", None, color=const_color(GREY))
        try:
            volume = self.volume(output.inputs["Volume"], name)
        except _Cycle as e:
            self.problem(f"node cycle through '{e}' in the volume (ignored)")
        self.aov_outputs(output.id_data)
        surface = self.source(output.inputs["Surface"], ())
        if volume is not None and (surface is None or surface[0] == "default"):
            # A Volume without a Surface: the boundary lets everything through (as Cycles').
            self.closure("transparent", None, color=const_color((1.0, 1.0, 1.0)))
        program = allocate_registers(eliminate_dead_code(self.ops))
        if program is None:
            self.problem(f"the material needs more than {MAX_REGISTERS} registers (grey "
                         "diffuse)")
            program = [("const", 0, GREY + (1.0,)),
                       ("closure", "diffuse", None, {"color": 0})]
        absorption = volume if isinstance(volume, tuple) else None
        medium = volume if isinstance(volume, (dict, list)) else None  # list: a volume program
        return CompiledShader(program, absorption, medium, dict(self.uv_used), list(self.problems),
                              displacement, displacement_method if displacement else 'BUMP')

    def aov_outputs(self, tree, ctx=()):
        """AOV Output nodes of the material's tree and of the node groups in it, nested too
        (Cycles expands every unmuted group, linked or not), whose name is one of the view
        layer's AOVs (Cycles: the Color input for a COLOR AOV, Value for a VALUE one; other
        names write nothing): an aov_output op each, run at the camera path's first surfaces.
        ctx: the group nodes the tree sits in (its Group Input reads the last one's inputs)."""
        aovs = getattr(self.uv_sets, "aovs", None)
        if not aovs or tree is None:
            return
        for node in tree.nodes:
            if getattr(node, "mute", False):
                continue
            if node.bl_idname == "ShaderNodeGroup":
                if len(ctx) > 32:  # a group inside itself (Blender refuses it; a file may not)
                    self.problem(f"node groups nested too deep at '{node.name}' (AOV Outputs left out)")
                    continue
                self.aov_outputs(node.node_tree, ctx + (node,))
                continue
            if node.bl_idname != "ShaderNodeOutputAOV":
                continue
            entry = aovs.get(node.aov_name)
            if entry is None:
                continue
            slot, kind = entry
            try:
                if kind == 'COLOR':
                    value = self.input(node, "Color", ctx, "color")
                else:
                    value = self.input(node, "Value", ctx, "float")
            except _Cycle as e:
                self.problem(f"node cycle through '{e}' into AOV Output '{node.name}' (ignored)")
                continue
            self.emit("color" if kind == 'COLOR' else "float", "aov_output", self.reg(value), slot, kind)

    def compile_light(self, output, name):
        """CompiledShader of a light's node tree (its Light Output's Surface: emission closures
        and the values they read), or None where it cannot be compiled (problems say why)."""
        return self._compile_emission(output, "light")

    def compile_world(self, output, name):
        """CompiledShader of a world's Surface (Background and Emission closures, the values
        they read, Texture Coordinate as Cycles' background gives it), or None where it cannot
        be compiled (problems say why)."""
        self.background = True
        return self._compile_emission(output, "world")

    def _compile_emission(self, output, what):
        """A light's or world's Surface (emission only) as a CompiledShader, or None."""
        try:
            self.shader_input(output.inputs["Surface"], (), None)
        except _Cycle as e:
            self.problem(f"node cycle through '{e}'")
            return None
        program = allocate_registers(eliminate_dead_code(self.ops))
        if program is None:
            self.problem(f"the {what}'s nodes need more than {MAX_REGISTERS} registers")
            return None
        return CompiledShader(program, None, None, dict(self.uv_used), list(self.problems))

    def _reset(self):
        self.ops = []
        self.nreg = 0
        self.const_regs = {}
        self.cache = {}
        self.visiting = set()
        self.uv_used = {}


def compile_material(mat, images, uv_sets, view_layer_ids=(), depsgraph=None, volume_grids=None,
                     density_scale=1.0, scene_grids=None):
    """CompiledShader of a bpy Material with nodes, or None when it has no Cycles output.
    view_layer_ids: the rendered view layer, its scene and world (View Layer attributes);
    depsgraph: the render's, for other objects' transforms (Texture Coordinate's Object)."""
    tree = mat.node_tree
    output = tree.get_output_node('CYCLES')
    if output is None:
        return None
    compiler = ShaderCompiler(images, uv_sets, material_index=mat.pass_index,
                              view_layer_ids=view_layer_ids, depsgraph=depsgraph, volume_grids=volume_grids,
                              scene_grids=scene_grids)
    compiler.material_key = mat.as_pointer()  # (owner of the UDIM tile sets it reads)
    compiler.volume_density_scale = float(density_scale)
    compiler.volume_interpolation = getattr(getattr(mat, "cycles", None), "volume_interpolation", 'LINEAR')
    return compiler.compile(
        output, mat.name, getattr(mat, "displacement_method", 'BUMP'))
