"""Blender materials → Pathlight materials: shader programs compiled from the node tree
(shader.py), with a (base colour, emission) summary for core builds without programs.
Plain data only: scene_writer.add_materials / put_material write it into the core scene."""

from typing import NamedTuple

from .shader import ImageTable, UvSets, compile_material

BLACK = (0.0, 0.0, 0.0)
GREY = (0.8, 0.8, 0.8)


class MaterialData(NamedTuple):
    name: str
    base_color: tuple  # Lambertian albedo, linear RGB (the summary for older core builds)
    emission: tuple  # emitted radiance (colour * strength), linear RGB
    program: list = None  # shader program (docs/core_api.md), None = use the two above
    volume_absorption: tuple = None  # ((r, g, b), density) or None
    use_schlick: bool = False
    uv_sets: dict = {}  # global uv-set index -> UV map name ("" = active render) it reads
    volume: dict = None  # the homogeneous medium inside (sigma_a, sigma_s, g, emission) or None
    pass_index: int = 0  # Blender's material pass index (the Material Index pass)
    # True displacement: the program of the offset at a vertex (CompiledShader.displacement)
    # and the method, 'DISPLACEMENT' or 'BOTH'; None / 'BUMP': none.
    displacement: list = None
    displacement_method: str = 'BUMP'


DEFAULT_MATERIAL = MaterialData("Pathlight Default", GREY, BLACK)


def cryptomatte_name(m):
    """The name MaterialData `m` has in Cryptomatte Material passes and manifests: its bpy
    material's, or for the empty slot Cycles' default surface shader's."""
    return "default_surface" if m is DEFAULT_MATERIAL else m.name


def socket_rgb(socket):
    return tuple(float(c) for c in socket.default_value[:3])


def scaled(rgb, s):
    return tuple(c * float(s) for c in rgb)


def surface_node(node_tree):
    """The shader node feeding the active output's Surface (through reroutes), or None."""
    output = node_tree.get_output_node('CYCLES')
    if output is None:
        return None
    socket = output.inputs["Surface"]
    seen = set()
    while True:
        links = [link for link in socket.links if not link.is_muted and link.is_valid]
        if not links:
            return None
        node = links[0].from_node
        if node.type != 'REROUTE':
            return node
        if node.as_pointer() in seen:  # a loop of reroutes
            return None
        seen.add(node.as_pointer())
        socket = node.inputs[0]


def flat_summary(node_tree):
    """(base colour, emission) of the node feeding the output: the material as older core
    builds (without shader programs) render it; constant values only."""
    node = surface_node(node_tree)
    if node is None:
        return BLACK, BLACK
    inputs = node.inputs
    if node.type == 'BSDF_DIFFUSE':
        return socket_rgb(inputs["Color"]), BLACK
    if node.type == 'EMISSION':
        return BLACK, scaled(socket_rgb(inputs["Color"]), inputs["Strength"].default_value)
    if node.type == 'BSDF_PRINCIPLED':
        return socket_rgb(inputs["Base Color"]), scaled(socket_rgb(inputs["Emission Color"]),
                                                      inputs["Emission Strength"].default_value)
    return GREY, BLACK


def view_layer_ids(depsgraph):
    """Where the Attribute node's View Layer attributes are looked up, in Blender's order: the
    rendered view layer, its scene, the scene's world."""
    scene = depsgraph.scene
    return tuple(x for x in (depsgraph.view_layer, scene, scene.world) if x is not None)


def convert_material(mat, warn, *args, **kw):
    """convert_material_data with the material's pass index."""
    data = convert_material_data(mat, warn, *args, **kw)
    return data if mat is None else data._replace(pass_index=int(getattr(mat, "pass_index", 0)))


def convert_material_data(mat, warn, images=None, uv_sets=None, use_schlick=False, view_layer_ids=(),
                          depsgraph=None, volume_grids=None, density_scale=1.0, scene_grids=None):
    """MaterialData for a bpy Material (or None = empty slot). Calls warn(msg) at most once:
    one message naming everything of the material that is approximated or unsupported.
    images/uv_sets: the scene's ImageTable and UvSets (fresh ones if None)."""
    if mat is None:
        return DEFAULT_MATERIAL
    if not mat.use_nodes or mat.node_tree is None:
        return MaterialData(mat.name, tuple(mat.diffuse_color[:3]), BLACK)
    images = images if images is not None else ImageTable()
    uv_sets = uv_sets if uv_sets is not None else UvSets()
    base, emission = flat_summary(mat.node_tree)
    try:
        compiled = compile_material(mat, images, uv_sets, view_layer_ids, depsgraph, volume_grids,
                                    density_scale, scene_grids)
    except Exception as e:  # a compiler bug must not stop the render
        warn(f"Material '{mat.name}': could not be compiled ({type(e).__name__}: {e}); "
             "using its base colour")
        return MaterialData(mat.name, base, emission)
    if compiled is None:  # no output node: Cycles renders black
        return MaterialData(mat.name, BLACK, BLACK, [], None, use_schlick)
    if compiled.problems:
        warn(f"Material '{mat.name}': " + "; ".join(compiled.problems))
    return MaterialData(mat.name, base, emission, compiled.program, compiled.volume_absorption,
                        use_schlick, compiled.uv_sets, compiled.volume,
                        displacement=compiled.displacement,
                        displacement_method=compiled.displacement_method)


class MaterialTable:
    """Converts each material once per export and numbers the results; holds the scene's
    images and uv sets that the materials' programs refer to."""

    def __init__(self, warn, use_schlick=False, view_layer_ids=(), depsgraph=None):
        self.warn = warn
        self.depsgraph = depsgraph  # (other objects' transforms in node trees)
        self.use_schlick = use_schlick
        self.view_layer_ids = view_layer_ids  # (view layer, scene, world): View Layer attributes
        self.images = ImageTable()
        self.uv_sets = UvSets()
        self.pass_uv_set = None  # the UV pass's uv set (every mesh's active render UV map), or None
        self.materials = []  # MaterialData, indexed by the numbers returned by index()
        self._index = {}
        self._names = {}  # key -> bpy material name
        self.volume_material_names = set()  # materials also compiled for volume objects
        self.grids = []  # the scene's core grids (volume objects', Point Density textures')

    def index(self, mat):
        key = mat.as_pointer() if mat is not None else 0
        if key not in self._index:
            self._index[key] = len(self.materials)
            self._names[key] = mat.name if mat is not None else ""
            self.materials.append(convert_material(mat, self.warn, self.images, self.uv_sets,
                                                   self.use_schlick, self.view_layer_ids, self.depsgraph,
                                                   scene_grids=self.grids))
        return self._index[key]

    def material_index(self, pointer):
        """The index of the material whose as_pointer() is `pointer`, None if not converted."""
        return self._index.get(pointer)

    def volume_index(self, mat, grids, density_scale=1.0):
        """The index of `mat` compiled for a volume object whose grids are `grids` ({name:
        (core grid id, channels)}): its Volume reads them, its surface lets light through."""
        key = ("volume", mat.as_pointer(), tuple(sorted(grids.items())), round(density_scale, 6))
        if key not in self._index:
            self._index[key] = len(self.materials)
            # No name: live edits (viewport) replace materials by name with a mesh's compile;
            # edits of these re-export instead (volume_material_names).
            self._names[key] = ""
            self.volume_material_names.add(mat.name)
            self.materials.append(convert_material(mat, self.warn, self.images, self.uv_sets,
                                                   self.use_schlick, self.view_layer_ids, self.depsgraph,
                                                   volume_grids=dict(grids), density_scale=density_scale,
                                                   scene_grids=self.grids))
        return self._index[key]

    def default_volume(self, grids, density_scale=1.0):
        """The index of Cycles' default volume shader (a volume object without a material):
        a Principled Volume of its defaults (colour 0.5, density 1 times the "density" grid)."""
        key = ("default volume", tuple(sorted(grids.items())), round(density_scale, 6))
        if key not in self._index:
            self._index[key] = len(self.materials)
            self._names[key] = ""
            half = (0.5 * density_scale,) * 3
            surface = [("const", 0, (1.0, 1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})]
            if "density" in grids:
                grid_id, channels = grids["density"]
                # sigma_s = sigma_a = 0.5 * density (Principled Volume: absorption colour black)
                volume = [("const", 0, (1.0, 1.0, 1.0, 1.0)), ("const", 1, half + (1.0,)),
                          ("volume_grid", 2, grid_id, "FAC", "LINEAR"),
                          ("mix", 3, 0, 1, 2, "MULTIPLY", False), ("const", 4, (0.0, 0.0, 0.0, 1.0)),
                          ("closure", "volume", None, {"sigma_a": 3, "sigma_s": 3, "g": 4})]
            else:
                volume = {"sigma_a": half, "sigma_s": half, "emission": (0.0, 0.0, 0.0), "g": 0.0}
            self.materials.append(MaterialData("Pathlight Default Volume", BLACK, BLACK, surface,
                                               None, False, {}, volume))
        return self._index[key]

    def material_names(self):
        """The bpy material name of each entry of `materials` ("" for the empty slot)."""
        names = [""] * len(self.materials)
        for key, i in self._index.items():
            names[i] = self._names.get(key, "")
        return names

    def uv_names(self, materials):
        """{global uv-set index: UV map name} that meshes with these materials must export."""
        names = {}
        for mat in materials:
            names.update(self.materials[self.index(mat)].uv_sets)
        if self.pass_uv_set is not None:
            names.setdefault(self.pass_uv_set, "")
        return names
