"""Blender materials → Pathlight's (base colour, emission) material, from constant node values."""

from typing import NamedTuple

BLACK = (0.0, 0.0, 0.0)
GREY = (0.8, 0.8, 0.8)


class MaterialData(NamedTuple):
    name: str
    base_color: tuple  # Lambertian albedo, linear RGB
    emission: tuple  # emitted radiance (colour * strength), linear RGB


DEFAULT_MATERIAL = MaterialData("Pathlight Default", GREY, BLACK)


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
    while True:
        links = [link for link in socket.links if not link.is_muted]
        if not links:
            return None
        node = links[0].from_node
        if node.type != 'REROUTE':
            return node
        socket = node.inputs[0]


def convert_material(mat, warn):
    """MaterialData for a bpy Material (or None = empty slot). Calls warn(msg) at most once."""
    if mat is None:
        return DEFAULT_MATERIAL
    if not mat.use_nodes or mat.node_tree is None:
        return MaterialData(mat.name, tuple(mat.diffuse_color[:3]), BLACK)

    node = surface_node(mat.node_tree)
    if node is None:
        return MaterialData(mat.name, BLACK, BLACK)  # nothing connected: Cycles renders black
    inputs = node.inputs
    if node.type == 'BSDF_DIFFUSE':
        base, emission = socket_rgb(inputs["Color"]), BLACK
        used = ("Color",)
    elif node.type == 'EMISSION':
        base = BLACK
        emission = scaled(socket_rgb(inputs["Color"]), inputs["Strength"].default_value)
        used = ("Color", "Strength")
    elif node.type == 'BSDF_PRINCIPLED':
        base = socket_rgb(inputs["Base Color"])
        emission = scaled(socket_rgb(inputs["Emission Color"]),
                          inputs["Emission Strength"].default_value)
        used = ("Base Color", "Emission Color", "Emission Strength")
    else:
        warn(f"Material '{mat.name}': shader node '{node.name}' ({node.bl_idname}) is not "
             "supported yet; using grey diffuse")
        return MaterialData(mat.name, GREY, BLACK)

    linked = [name for name in used if inputs[name].is_linked]
    if linked:
        warn(f"Material '{mat.name}': linked input(s) {', '.join(linked)} of '{node.name}' "
             "are not supported yet; using their constant values")
    return MaterialData(mat.name, base, emission)


class MaterialTable:
    """Converts each material once per export and numbers the results."""

    def __init__(self, warn):
        self.warn = warn
        self.materials = []  # MaterialData, indexed by the numbers returned by index()
        self._index = {}

    def index(self, mat):
        key = mat.as_pointer() if mat is not None else 0
        if key not in self._index:
            self._index[key] = len(self.materials)
            self.materials.append(convert_material(mat, self.warn))
        return self._index[key]
