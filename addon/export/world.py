"""World → constant background radiance, or an equirectangular environment image.

Supported node graph (Cycles' meaning): [Texture Coordinate (Generated/Object)] → [Mapping]
→ Environment Texture (equirectangular) or Sky Texture (Nishita, Preetham, Hosek / Wilkie)
→ Background/Emission
Color, times Strength.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from .material import BLACK, scaled, socket_rgb, surface_node
from .image import is_srgb_bytes, read_pixels, rgb_of, to_scene_linear


@dataclass
class WorldTexture:
    pixels: np.ndarray  # float32 (H, W, 3) scene-linear RGB, row 0 = bottom (image.pixels order)
    strength: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3, dtype=np.float32))
    # rotation: world direction d -> lookup direction t = rotation @ d (the core's convention)
    name: str = ""
    # An 8-bit sRGB image's byte / 255 values (H, W, 3), which the core filters before decoding
    # them, as Cycles (NODE_IMAGE_COMPRESS_AS_SRGB); None: other images (pixels are what it reads).
    encoded: np.ndarray = None


@dataclass
class WorldSky:
    """Blender's Sky Texture, computed by the core: the node's settings as
    pc.Scene.set_world_sky (Nishita: radians, metres, densities), set_world_preetham (sun
    direction, turbidity) or set_world_hosek (sun direction, turbidity, ground albedo) takes
    them."""
    params: dict
    strength: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3, dtype=np.float32))
    name: str = ""
    kind: str = "nishita"  # or "preetham", "hosek"


@dataclass
class WorldProgram:
    """A world whose Surface is not the fast path's graph: its node tree compiled into a
    program (pc.Scene.set_world_program), evaluated per escaped ray with the ray's Light Path
    state; a width x height map of it steers the light samples."""
    program: list
    images: list  # shader.ImageData the program's image ops index (scene_writer renumbers them)
    width: int = 1024
    height: int = 512
    name: str = ""


def sky_params(node):
    """set_world_sky's keyword arguments for a Nishita Sky Texture node."""
    return {"sun_elevation": float(node.sun_elevation), "sun_rotation": float(node.sun_rotation),
            "sun_size": float(node.sun_size), "sun_intensity": float(node.sun_intensity),
            "sun_disc": bool(node.sun_disc), "altitude": float(node.altitude),
            "air": float(node.air_density), "dust": float(node.dust_density),
            "ozone": float(node.ozone_density)}


def linked_node(socket):
    """The node feeding `socket` (through reroutes and ignoring muted links), or None."""
    while True:
        links = [link for link in socket.links if not link.is_muted]
        if not links:
            return None, None
        link = links[0]
        if link.from_node.type != 'REROUTE':
            return link.from_node, link.from_socket
        socket = link.from_node.inputs[0]


def _background_node(world, warn):
    """(Background/Emission node, None) or (None, fallback colour) for a world."""
    if world is None:
        return None, BLACK
    if not world.use_nodes or world.node_tree is None:
        return None, tuple(world.color)
    node = surface_node(world.node_tree)
    if node is None:
        return None, BLACK  # nothing connected: Cycles renders a black world
    if node.type in {'BACKGROUND', 'EMISSION'}:  # Cycles treats both alike in a world
        return node, None
    warn(f"World '{world.name}': node '{node.name}' ({node.bl_idname}) is not supported yet; "
         "using the world's colour")
    return None, tuple(world.color)


def world_color(world, warn):
    """Background radiance (colour * strength) as an RGB tuple: the world's constant colour,
    also the fallback when its texture cannot be used (each problem is warned about by
    world_texture; this warns only about what a constant world cannot show)."""
    node, fallback = _background_node(world, warn)
    if node is None:
        return fallback
    color, strength = node.inputs["Color"], node.inputs["Strength"]
    linked = [s.name for s in (color, strength) if s.is_linked]
    source, _ = linked_node(color)
    if source is not None and source.type in {'TEX_ENVIRONMENT', 'TEX_SKY'}:
        linked.remove("Color")  # world_texture() handles (or warns about) these
    if linked:
        warn(f"World '{world.name}': linked input(s) {', '.join(linked)} of '{node.name}' are "
             "not supported yet; using their constant values")
    return scaled(socket_rgb(color), strength.default_value)


def export_world(world, warn, frame=None):
    """(constant colour, WorldTexture / WorldSky or None, WorldProgram or None) of a world.
    Today's fast path (a constant, or Background / Emission of an equirectangular Environment
    Texture or a Sky Texture through an optional Mapping, times a constant Strength) where the
    world is exactly that graph, bit for bit as before; any other graph becomes a program, the
    fast path's warnings standing where the program cannot be compiled. frame: the scene
    frame, which picks an image sequence's frame (None: the file the image's path names)."""
    notes = []
    color = world_color(world, notes.append)
    # A graph the colour already shows beyond the fast path is compiled before the fast path
    # reads its image: an HDRI is read once, by the program's image table, not twice.
    tried = bool(notes)
    if tried:
        program = world_program(world, warn, frame)
        if program is not None:
            return color, None, program
    texture = world_texture(world, notes.append, frame)
    if notes and not tried:
        program = world_program(world, warn, frame)
        if program is not None:
            return color, None, program
    for note in notes:
        warn(note)
    return color, texture, None


def world_sampled(world):
    """False where World ▸ Settings ▸ Sampling Method is None: Cycles then adds no background
    light (sync_background_light), so the world is no light to sample and only rays that escape
    find it (weight 1); True for Automatic and Manual, and without a world."""
    cycles = getattr(world, "cycles", None) if world is not None else None
    return getattr(cycles, "sampling_method", 'AUTOMATIC') != 'NONE'


def _map_size(world, tree):
    """Cycles' background map size: Settings ▸ Sampling's Map Resolution (Manual), else the
    largest Environment Texture image in the tree, else 1024 x 512 (capped at 4096 x 2048)."""
    cycles = getattr(world, "cycles", None)
    method = getattr(cycles, "sampling_method", 'AUTOMATIC')
    width = height = 0
    if method == 'MANUAL':
        res = int(getattr(cycles, "sample_map_resolution", 1024))
        width, height = res, res // 2
    else:
        for node in tree.nodes:
            image = getattr(node, "image", None) if node.type == 'TEX_ENVIRONMENT' else None
            if image is not None and image.size[0] > 0 and image.size[1] > 0:
                width, height = max(width, int(image.size[0])), max(height, int(image.size[1]))
    if width <= 0 or height <= 0:
        width, height = 1024, 512
    width = min(max(width + (width & 1), 8), 4096)
    height = min(max(height + (height & 1), 4), 2048)
    return width, height


def world_program(world, warn, frame=None):
    """WorldProgram of a world's Surface compiled by the shader compiler (its problems warned
    about, naming the nodes, each with its fallback), or None where it cannot be compiled."""
    if world is None or not world.use_nodes or world.node_tree is None:
        return None
    output = world.node_tree.get_output_node('CYCLES')
    if output is None or "Surface" not in output.inputs:
        return None
    from .shader import ImageTable, UvSets, ShaderCompiler
    images = ImageTable()
    compiler = ShaderCompiler(images, UvSets())
    compiler.frame = frame  # (Environment Textures of image sequences)
    try:
        compiled = compiler.compile_world(output, world.name)
    except Exception as e:  # a compiler bug must not stop the render
        warn(f"World '{world.name}': its nodes could not be compiled ({type(e).__name__}: {e})")
        return None
    if compiler.problems:
        warn(f"World '{world.name}': " + "; ".join(compiler.problems))
    if compiled is None:
        return None
    width, height = _map_size(world, world.node_tree)
    return WorldProgram(compiled.program, images.images, width, height, world.name)


def world_volume(world, warn):
    """The world's Volume as the core's medium: a homogeneous-medium dict (sigma_a, sigma_s, g,
    emission) where its inputs are constant, a volume program (a list of ops, as materials'
    volumes: shader.ShaderCompiler) where they vary in space, or None. The core tracks a program
    over the scene's bounds (docs/design/volumes.md "World volumes")."""
    if world is None or not world.use_nodes or world.node_tree is None:
        return None
    output = world.node_tree.get_output_node('CYCLES')
    socket = output.inputs.get("Volume") if output is not None else None
    if socket is None or not socket.is_linked:
        return None
    from .shader import ShaderCompiler
    images = []
    compiler = ShaderCompiler(images, {})
    try:
        vol = compiler.volume(socket, world.name)
    except Exception as e:  # a compiler bug must not stop the render
        warn(f"World '{world.name}': its Volume could not be compiled ({type(e).__name__}: {e}); ignored")
        return None
    if compiler.problems:
        warn(f"World '{world.name}' volume: " + "; ".join(compiler.problems))
    if isinstance(vol, list) and images:
        # (the world's program would index the materials' image table, which does not hold them)
        warn(f"World '{world.name}': image textures in the world's Volume are not supported yet; "
             "the Volume is ignored")
        return None
    if isinstance(vol, tuple):  # a lone Volume Absorption
        (color, density) = vol
        d = max(float(density), 0.0) if math.isfinite(density) else 0.0
        vol = {"sigma_a": tuple(max(1.0 - min(max(c, 0.0), 1.0), 0.0) * d for c in color)}
    return vol


def warn_open_world_volume(stats, world, warn):
    """After commit: a warning where a heterogeneous world Volume meets rays that leave the scene
    (the core's probe rays from the camera and lights escaped). Beyond the scene's bounds the
    core's world medium is empty, and Cycles 4.5 marches such rays in one step of about
    FLT_MAX / Max Steps, reading the density ~1e35 units away for the whole ray: the two differ
    there, and neither is fog."""
    open_fraction = stats.get("world_volume_open", 0.0)
    if open_fraction > 0.0:
        name = world.name if world is not None else "World"
        warn(f"World '{name}': its Volume varies in space and {100.0 * open_fraction:.0f} % of the "
             "rays probed from the camera and lights leave the scene; the world's fog ends at the "
             "scene's bounds (Cycles marches such rays in one huge step and differs): enclose the "
             "scene (a room, a large box) for a defined result")


def world_texture(world, warn, frame=None):
    """WorldTexture for a world lit by an equirectangular Environment Texture, WorldSky for a
    Sky Texture, else None
    (then world_color() is the background). Problems are warned about and fall back to the
    constant colour."""
    node, _ = _background_node(world, lambda msg: None)  # world_color() warns about these
    if node is None:
        return None
    source, _ = linked_node(node.inputs["Color"])
    if source is None:
        return None
    if source.type == 'TEX_SKY':
        what = f"World '{world.name}': Sky Texture '{source.name}'"
        # Cycles applies the node's texture mapping (Python-only since 2.8) after the Vector
        # input, also to Nishita's unavailable one (the view direction).
        mapped = _texture_mapping_rotation(getattr(source, "texture_mapping", None), what, warn)
        if source.sky_type in {'PREETHAM', 'HOSEK_WILKIE'}:
            params = {"sun_direction": tuple(float(c) for c in source.sun_direction),
                      "turbidity": float(source.turbidity)}
            kind = "preetham"
            if source.sky_type == 'HOSEK_WILKIE':
                params["ground_albedo"] = float(source.ground_albedo)
                kind = "hosek"
            rotation = mapped @ _vector_rotation(source.inputs["Vector"], what, warn, unit=True)
            return WorldSky(params, float(node.inputs["Strength"].default_value), rotation,
                            source.name, kind)
        if source.sky_type != 'NISHITA':
            warn(f"{what}: the {source.sky_type} sky type is not supported yet (Nishita, "
                 "Preetham and Hosek / Wilkie are); using a constant background (the "
                 "Background colour)")
            return None
        # Blender 4.5 makes Nishita's Vector socket unavailable (get() does not find it), and
        # Cycles then looks the sky up along the view direction itself.
        vector = source.inputs.get("Vector")
        rotation = mapped @ (np.eye(3, dtype=np.float32) if vector is None
                             else _vector_rotation(vector, what, warn, unit=True))
        return WorldSky(sky_params(source), float(node.inputs["Strength"].default_value),
                        rotation, source.name)
    if source.type != 'TEX_ENVIRONMENT':
        return None
    what = f"World '{world.name}': Environment Texture '{source.name}'"
    if source.projection != 'EQUIRECTANGULAR':
        warn(f"{what}: {source.projection.lower()} projection is not supported; using a "
             "constant background")
        return None
    if source.interpolation != 'Linear':
        warn(f"{what}: {source.interpolation} interpolation is not supported; using Linear")
    encoded = [] if source.image is not None and is_srgb_bytes(source.image) else None
    pixels = image_pixels(source.image, what, warn, getattr(source, "image_user", None), frame,
                          encoded)
    if pixels is None:
        return None
    rotation = _vector_rotation(source.inputs["Vector"], what, warn)
    return WorldTexture(pixels, float(node.inputs["Strength"].default_value), rotation,
                        source.image.name, encoded[0] if encoded else None)


# ---------------------------------------------------------------- the lookup direction

def _euler_matrix(xyz):
    """Blender's XYZ Euler rotation matrix (Rz @ Ry @ Rx), as the Mapping node uses."""
    from mathutils import Euler  # only importable inside Blender
    return np.array(Euler(tuple(float(a) for a in xyz), 'XYZ').to_matrix(), np.float64)


def _texture_mapping_rotation(tm, what, warn):
    """float32 3x3 matrix of a texture node's texture_mapping (bpy TexMapping) as Cycles
    applies it to a direction (TextureMapping::compute_transform: the axis projection first,
    then translation-rotation-scale, inverted for TEXTURE, transposed inverse for NORMAL), where
    it keeps directions unit: rotations, axis permutations and scales of +-1. Cycles does not
    normalise the vector a sky reads, so other scales, a translation of a POINT or TEXTURE
    mapping and the min/max clamps change the sky in ways a rotation cannot: warned, ignored."""
    if tm is None:
        return np.eye(3, dtype=np.float32)
    vtype = tm.vector_type
    axes = (tm.mapping_x, tm.mapping_y, tm.mapping_z)
    project = np.eye(3)
    if axes != ('X', 'Y', 'Z'):
        if sorted(axes) == ['X', 'Y', 'Z']:
            project = np.zeros((3, 3))
            for row, axis in enumerate(axes):
                project[row, "XYZ".index(axis)] = 1.0
        else:
            warn(f"{what}: texture mapping axes {'/'.join(axes)} (not a permutation of X, Y, "
                 "Z) are not supported; ignored")
    s = np.asarray(tm.scale, np.float64)
    if not np.allclose(np.abs(s), 1.0, rtol=0.0, atol=1e-6):
        warn(f"{what}: texture mapping scale {tuple(round(float(x), 4) for x in s)} is not "
             "supported (only rotations keep the sky's lookup direction unit); ignored")
        s = np.ones(3)
    flip = np.diag(np.sign(s))
    if any(tm.translation) and vtype in {'POINT', 'TEXTURE'}:
        warn(f"{what}: texture mapping location is not supported for a sky; ignored")
    if tm.use_min or tm.use_max:
        warn(f"{what}: texture mapping min / max clamping is not supported; ignored")
    r = _euler_matrix(tm.rotation) if any(tm.rotation) else np.eye(3)
    # t = M P d: M = R S (POINT, VECTOR), (R S)^-1 = S R^T (TEXTURE), (R S)^-T = R S (NORMAL,
    # then normalised: the same direction), with S = S^-1 = flip.
    m = flip @ r.T if vtype == 'TEXTURE' else r @ flip
    return (m @ project).astype(np.float32)


def _vector_rotation(vector_socket, what, warn, unit=False):
    """The 3x3 matrix taking a world direction to the texture lookup direction, for what
    feeds the Environment Texture's Vector: nothing / Texture Coordinate (the direction
    itself) or a Mapping node (its rotation; uniform scale does not change a direction the
    Environment Texture normalises). unit: the texture reads the vector as it is (the Sky
    Texture: Cycles does not normalise it), so only scales of +-1 keep it; others are warned."""
    node, out_socket = linked_node(vector_socket)
    rotation = np.eye(3)
    if node is not None and node.type == 'MAPPING':
        mapping = node
        # Sockets a vector type does not use (Location of VECTOR/NORMAL, ...) are absent.
        loc, rot, scale = (mapping.inputs.get(name) for name in ("Location", "Rotation", "Scale"))
        if any(s is not None and s.is_linked for s in (loc, rot, scale)):
            warn(f"{what}: linked Mapping inputs are not supported; using their constant values")
        vtype = mapping.vector_type
        s = np.ones(3) if scale is None else np.asarray(scale.default_value, np.float64)
        if not (np.abs(s) > 0).all() or not np.allclose(np.abs(s), np.abs(s[0]), rtol=1e-5):
            warn(f"{what}: non-uniform Mapping scale is not supported; ignoring the scale")
            s = np.ones(3)
        elif unit and not np.allclose(np.abs(s), 1.0, rtol=0.0, atol=1e-6):
            warn(f"{what}: a Mapping scale other than 1 is not supported (Cycles does not "
                 "renormalise the sky's lookup vector); ignoring the scale")
            s = np.sign(s)
        if loc is not None and vtype in {'POINT', 'TEXTURE'} and np.any(
                np.asarray(loc.default_value) != 0):
            warn(f"{what}: Mapping location is not supported for a world (it does not move "
                 "a direction); ignored")
        flip = np.diag(np.sign(s))  # a uniform negative scale mirrors the direction
        r = np.eye(3) if rot is None else _euler_matrix(rot.default_value)
        # POINT/VECTOR/NORMAL: t = R (S d); TEXTURE is the inverse transform: t = S⁻¹ Rᵀ d.
        rotation = flip @ r.T if vtype == 'TEXTURE' else r @ flip
        node, out_socket = linked_node(mapping.inputs["Vector"])
        if node is None:
            warn(f"{what}: Mapping without an input vector is not supported; using the "
                 "view direction")
    if node is not None:
        ok = node.type == 'TEX_COORD' and out_socket.name in {"Generated", "Object"} and (
            out_socket.name != "Object" or node.object is None)
        if not ok:
            warn(f"{what}: texture coordinates from '{node.name}' "
                 f"({out_socket.name}) are not supported; using the view direction")
    return rotation.astype(np.float32)


# ---------------------------------------------------------------- image pixels

def image_pixels(image, what, warn, user=None, frame=None, encoded=None):
    """float32 (H, W, 3) scene-linear RGB of a bpy Image (row 0 = bottom), or None (with a
    warning) when there is none or it cannot be read. Blender gives float images (.exr,
    .hdr) already converted to scene linear, and byte images as raw byte/255 values in the
    image's colour space, which we linearise here (Cycles does the same). user, frame: the
    node's ImageUser and the scene frame (a sequence's frame, as read_pixels). encoded: a list
    that gets the raw byte / 255 RGB before linearising (an sRGB byte image's, which the core
    filters encoded)."""
    if image is None:
        warn(f"{what} has no image; using a constant background")
        return None
    notes = []
    buf, why = read_pixels(image, user if frame is not None else None, frame, notes)
    for note in notes:
        warn(f"{what}: {note}")
    if buf is None:
        warn(f"{what}: {why}; using a constant background")
        return None
    raw = rgb_of(buf)
    if encoded is not None:
        encoded.append(np.clip(np.nan_to_num(raw, nan=0.0), 0.0, 1.0).astype(np.float32))
    rgb, note = to_scene_linear(image, raw)
    if note:
        warn(f"{what}: {note}")
    if not np.isfinite(rgb).all() or (rgb < 0).any():
        warn(f"{what}: image '{image.name}' has negative or non-finite pixels; clamped to 0")
        rgb = np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)
        np.maximum(rgb, 0.0, out=rgb)
    return rgb
