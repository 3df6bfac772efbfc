"""Blender light objects → keyword arguments of the core's add_*_light, in Cycles' units.

Cycles (intern/cycles/blender/light.cpp, scene/light.cpp) takes the light's power
P = colour * energy * 2^exposure (* temperature colour) and divides it by the emitter's
"area" when `normalize` is on (the default): point/spot 4π (r = 0) -> intensity P/(4π);
area π·A -> radiance P/(π·A) with A the world-space area; sun: strength is already the
irradiance E in W/m². With `normalize` off Cycles skips that division, i.e. P is multiplied
by the same area; we do exactly that.
"""

import math
from dataclasses import dataclass

import numpy as np

from .material import surface_node


@dataclass
class LightData:
    kind: str  # "point" | "spot" | "sun" | "area" | "portal": the core's scene.add_<kind>_light
    name: str
    args: dict  # keyword arguments of that call
    # Light linking: (light_mask, shadow_mask) for the core's set_light_links, or None.
    links: tuple = None
    # The images (shader.ImageData) that args["shader"]'s image ops index (scene_writer adds
    # them and renumbers the ops).
    images: list = None
    # Object ▸ Shading ▸ Light Group: the name of the view layer's light group it is in ("":
    # none; a name not in the view layer's list is none too, as Cycles).
    lightgroup: str = ""
    # Cycles' light Max Bounces (light.cycles.max_bounces; 1024 is Cycles' default).
    max_bounces: int = 1024


@dataclass
class LightShaderData:
    program: list  # a shader program ending in emission closures (docs/core_api.md)
    images: list  # shader.ImageData its image ops index
    power: float  # Cycles' estimate of the tree's emission (luminance), for the light's power


def _finite_nonneg(values, what, name, warn):
    """values as floats, NaN/inf/negative replaced by 0 (with a warning): never crash the core."""
    arr = np.asarray(values, np.float64)
    bad = ~np.isfinite(arr) | (arr < 0.0)
    if bad.any():
        shown = tuple(arr.tolist()) if arr.ndim else float(arr)
        warn(f"Light '{name}': invalid {what} {shown} (negative or not finite) clamped to 0")
        arr = np.where(bad, 0.0, arr)
    return arr


# Cycles' IES Texture where it has no profile (file missing or unreadable): kernel_ies_interp's
# fallback value, so such a light still emits, uniformly (measured in Blender 4.5).
IES_FALLBACK = 100.0


def _linked_node(socket):
    """(node, output socket) feeding `socket` through reroutes, or (None, None)."""
    seen = set()
    while True:
        links = [link for link in socket.links if not link.is_muted and link.is_valid]
        if not links:
            return None, None
        node = links[0].from_node
        if node.type != 'REROUTE':
            return node, links[0].from_socket
        if node.as_pointer() in seen:
            return None, None
        seen.add(node.as_pointer())
        socket = node.inputs[0]


def _ies_source(node):
    """(bytes of the IES node's profile, where it came from) or (None, why not)."""
    if node.mode == 'INTERNAL':
        text = node.ies
        if text is None:
            return None, "no Text datablock"
        return text.as_string().encode("utf-8", "surrogateescape"), f"text '{text.name}'"
    import bpy  # (only here: the rest of this module runs without Blender in unit tests)
    raw = node.filepath
    if not raw:
        return None, "no file path"
    path = bpy.path.abspath(raw, library=node.id_data.library)
    try:
        with open(path, "rb") as f:
            return f.read(), f"file '{raw}'"
    except OSError as e:
        return None, f"file '{raw}' unreadable ({e.strerror or e})"


def ies_profile(node, report, who=""):
    """The core's IesProfile of an IES Texture node, or None where it has none (reported;
    Cycles then uses its fallback value). who: what to name in the report ("Light 'x': ")."""
    data, where = _ies_source(node)
    if data is not None:
        from ..core import get_core
        try:
            return get_core().IesProfile(data)
        except ValueError as e:
            where = f"{where}: {e}"
    report(f"{who}IES Texture without a usable profile ({where}); rendered without "
           f"it, at Cycles' fallback of {IES_FALLBACK:g} x Strength")
    return None


def _ies_profile(node, name, warn):
    return ies_profile(node, warn, f"Light '{name}': ")


def _ies_chain(strength, name, warn):
    """(IES node, constant factor) where an Emission's Strength is IES Texture Fac, maybe
    multiplied or divided by a constant through one Math node; else None."""
    node, out = _linked_node(strength)
    scale = 1.0
    if node is not None and node.type == 'MATH' and not node.mute and not node.use_clamp:
        a, b = node.inputs[0], node.inputs[1]
        if node.operation == 'MULTIPLY' and a.is_linked != b.is_linked:
            const = b if a.is_linked else a
            scale = float(const.default_value)
            node, out = _linked_node(a if a.is_linked else b)
        elif node.operation == 'DIVIDE' and a.is_linked and not b.is_linked and b.default_value != 0.0:
            scale = 1.0 / float(b.default_value)
            node, out = _linked_node(a)
        else:
            return None
    if node is None or node.type != 'TEX_IES' or node.mute or out.name != "Fac":
        return None
    if node.inputs["Vector"].is_linked or node.inputs["Strength"].is_linked:
        warn(f"Light '{name}': IES Texture with a linked Vector or Strength is not supported; "
             "using its defaults (the light's own direction, the Strength value)")
    return node, scale * float(node.inputs["Strength"].default_value)


_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _emission_estimate(socket):
    """Cycles' estimate of the emission a shader socket gives (scene/shader.cpp
    output_estimate_emission): Emission (or Principled) nodes' unlinked Color and Strength, a
    linked Color as 1, a linked Strength through Light Falloff and IES Texture as their
    Strength, sums over Add Shader, a Mix Shader's mean; other nodes 1. RGB."""
    node, _ = _linked_node(socket)
    if node is None:
        return np.zeros(3)
    t = node.type
    if t in {'EMISSION', 'BACKGROUND', 'BSDF_PRINCIPLED'}:
        principled = t == 'BSDF_PRINCIPLED'
        color = node.inputs["Emission Color" if principled else "Color"]
        strength = node.inputs["Emission Strength" if principled else "Strength"]
        est = np.ones(3)
        if not color.is_linked:
            est = est * np.asarray(color.default_value[:3], np.float64)
        return est * (_emission_estimate(strength) if strength.is_linked
                      else float(strength.default_value))
    if t in {'LIGHT_FALLOFF', 'TEX_IES'}:
        strength = node.inputs["Strength"]
        return (_emission_estimate(strength) if strength.is_linked
                else np.full(3, float(strength.default_value)))
    if t == 'ADD_SHADER':
        return _emission_estimate(node.inputs[0]) + _emission_estimate(node.inputs[1])
    if t == 'MIX_SHADER':
        fac = node.inputs[0]
        f = 0.5 if fac.is_linked else min(max(float(fac.default_value), 0.0), 1.0)
        return (1.0 - f) * _emission_estimate(node.inputs[1]) + f * _emission_estimate(node.inputs[2])
    return np.ones(3)


def _light_shader(light, name, warn):
    """LightShaderData of a light's node tree compiled by the shader compiler, or None where it
    cannot be (warned)."""
    from .shader import ImageTable, UvSets
    from .shader.compiler import ShaderCompiler
    tree = light.node_tree
    output = tree.get_output_node('CYCLES')
    if output is None or "Surface" not in output.inputs:
        return None
    images = ImageTable()
    compiler = ShaderCompiler(images, UvSets())
    compiled = compiler.compile_light(output, name)
    for problem in compiler.problems:
        warn(f"Light '{name}': {problem}")
    if compiled is None:
        return None
    est = np.nan_to_num(_emission_estimate(output.inputs["Surface"]))
    return LightShaderData(compiled.program, images.images, float(abs(est) @ _LUMA))


def _node_tree_factor(light, name, warn):
    """(colour multiplier, IesProfile or None, LightShaderData or None) of a light's node
    tree. A constant Emission node is applied exactly (Cycles multiplies the light's strength
    by the shader's emission); an Emission whose Strength is an IES Texture (maybe times a
    constant) adds the profile, a direction-dependent factor the core applies; any other tree
    is compiled into a program the core evaluates at each light sample (light_shader.h)."""
    if not light.use_nodes or light.node_tree is None:
        return np.ones(3), None, None
    node = surface_node(light.node_tree)
    if node is None:
        return np.zeros(3), None, None  # nothing connected to the Light Output: Cycles emits nothing
    if node.type == 'EMISSION' and not node.inputs["Color"].is_linked:
        color = np.asarray(node.inputs["Color"].default_value[:3], np.float64)
        strength = node.inputs["Strength"]
        if not strength.is_linked:
            return color * float(strength.default_value), None, None
        chain = _ies_chain(strength, name, warn) if light.type in {'POINT', 'SPOT', 'AREA'} else None
        if chain is not None:
            ies_node, scale = chain
            profile = _ies_profile(ies_node, name, warn)
            return color * scale * (1.0 if profile is not None else IES_FALLBACK), profile, None
    shader = _light_shader(light, name, warn)
    if shader is not None:
        return np.ones(3), None, shader
    warn(f"Light '{name}': its node tree could not be compiled; ignoring the light's nodes")
    return np.ones(3), None, None


def light_power(light, name, warn, ies=None, shader=None):
    """RGB power (W) as Cycles computes it: colour * energy * 2^exposure, times the
    temperature colour and a constant Emission node, if any. ies: a list that receives the
    light's IesProfile (None without one); shader: one that receives its LightShaderData (None
    without one: the tree is constant, or absent)."""
    color = np.asarray(light.color[:3], np.float64)
    if getattr(light, "use_temperature", False):
        color = color * np.asarray(light.temperature_color[:3], np.float64)
    energy = float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0))
    factor, profile, program = _node_tree_factor(light, name, warn)
    if ies is not None:
        ies.append(profile)
    if shader is not None:
        shader.append(program)
    color = color * factor
    return _finite_nonneg(color, "colour", name, warn) * float(
        _finite_nonneg(energy, "power", name, warn))


def _convert_portal(light, name, matrix, warn):
    """A light portal (an area light with Cycles' Portal on): no emitter; the core samples the
    world through it from its emission side (-Z), as Cycles. Cycles takes every area shape
    (ellipses and disks sampled by area), and so do we; other light types are not portals."""
    if light.type != 'AREA':
        warn(f"Light '{name}': only area lights can be portals; ignored")
        return None
    m = np.array(matrix, np.float64)
    if not np.isfinite(m).all():
        warn(f"Light '{name}': non-finite transform; portal skipped")
        return None
    size_x = float(_finite_nonneg(light.size, "size", name, warn))
    size_y = size_x if light.shape in {'SQUARE', 'DISK'} else float(
        _finite_nonneg(light.size_y, "size", name, warn))
    if not size_x * size_y > 0:
        return None  # no opening
    return LightData("portal", name, dict(
        matrix=m.astype(np.float32), size_x=size_x, size_y=size_y,
        ellipse=light.shape in {'DISK', 'ELLIPSE'}))


def convert_light(obj, matrix, warn):
    """LightData for one light instance (obj: evaluated light object, matrix: (4, 4)
    world matrix of this instance), or None when it emits nothing."""
    light = obj.data
    name = obj.original.name if obj.original is not None else obj.name
    cycles = getattr(light, "cycles", None)
    if cycles is not None and getattr(cycles, "is_portal", False):
        return _convert_portal(light, name, matrix, warn)
    ies, shaders = [], []
    power = light_power(light, name, warn, ies, shaders)
    if not power.any():
        return None
    ies = dict(ies=ies[0]) if ies[0] is not None else {}
    m = np.array(matrix, np.float64)
    if not np.isfinite(m).all():
        warn(f"Light '{name}': non-finite transform; skipped")
        return None
    shader, images = {}, None
    if shaders[0] is not None:
        shader = dict(shader=shaders[0].program, shader_power=shaders[0].power)
        images = shaders[0].images
    # Cycles' "Cast Shadow" is the light's own flag; it ignores the light object's Shadow ray
    # visibility (measured: same image with visible_shadow off), and so do we.
    cast_shadow = bool(light.use_shadow)
    normalize = getattr(light, "normalize", True)
    # Cycles' Multiple Importance (rays find the light and MIS weighs them against light
    # samples; off: light samples only) and the light object's Ray Visibility, as Cycles
    # applies them (core/scene/light.h): camera rays see lights visible to the camera, other rays
    # the Multiple Importance lights visible to their kind; light samples leave out the closures
    # of the kinds a light is invisible to. (Shadow visibility: see cast_shadow above.)
    flags = dict(
        use_mis=bool(getattr(cycles, "use_multiple_importance_sampling", True)) if cycles is not None else True,
        visible_camera=bool(getattr(obj, "visible_camera", True)),
        visible_diffuse=bool(getattr(obj, "visible_diffuse", True)),
        visible_glossy=bool(getattr(obj, "visible_glossy", True)),
        visible_transmission=bool(getattr(obj, "visible_transmission", True)),
        visible_volume=bool(getattr(obj, "visible_volume_scatter", True)))

    if light.type in {'POINT', 'SPOT'}:
        radius = float(_finite_nonneg(light.shadow_soft_size, "radius", name, warn))
        if not normalize:  # Cycles' sphere area, 4 for a point: intensity = P * area / (4π)
            power = power * (4.0 * math.pi * radius * radius if radius > 0 else 4.0)
        intensity = tuple((power / (4.0 * math.pi)).tolist())
        # Soft Falloff off: Cycles' emitting sphere (of the same radiance as the soft disk).
        flags["soft_falloff"] = bool(getattr(light, "use_soft_falloff", True))
        if light.type == 'POINT':
            return LightData("point", name, dict(
                position=tuple(m[:3, 3].tolist()), intensity=intensity, radius=radius,
                cast_shadow=cast_shadow, **flags, **ies,
                **(dict(ies_matrix=m.astype(np.float32)) if ies else {}),
                **(dict(shader_matrix=m.astype(np.float32), **shader) if shader else {})), images=images)
        spot_size = float(np.clip(np.nan_to_num(light.spot_size, nan=math.pi), 1e-4, math.pi))
        spot_blend = float(np.clip(np.nan_to_num(light.spot_blend), 0.0, 1.0))
        return LightData("spot", name, dict(
            matrix=m.astype(np.float32), intensity=intensity, radius=radius,
            spot_size=spot_size, spot_blend=spot_blend, cast_shadow=cast_shadow, **flags, **ies,
            **shader), images=images)

    if light.type == 'SUN':
        z = m[:3, 2]
        norm = np.linalg.norm(z)
        if not norm > 0:
            return None  # zero-scaled: no direction
        angle = float(np.clip(np.nan_to_num(light.angle), 0.0, math.pi))
        if not normalize and angle > 0:  # Cycles' sun "area": π sin²(angle/2)
            power = power * (math.pi * math.sin(angle / 2) ** 2)
        return LightData("sun", name, dict(
            direction=tuple((z / norm).tolist()), irradiance=tuple(power.tolist()),
            angle=angle, cast_shadow=cast_shadow, **flags,
            **(dict(shader_matrix=m.astype(np.float32), **shader) if shader else {})), images=images)

    if light.type == 'AREA':
        size_x = float(_finite_nonneg(light.size, "size", name, warn))
        size_y = size_x if light.shape in {'SQUARE', 'DISK'} else float(
            _finite_nonneg(light.size_y, "size", name, warn))
        ellipse = light.shape in {'DISK', 'ELLIPSE'}
        # World-space area: the object's scale stretches the light (Cycles: |axis| * size).
        area = np.linalg.norm(m[:3, 0]) * size_x * np.linalg.norm(m[:3, 1]) * size_y
        if ellipse:
            area *= math.pi / 4.0
        if not area > 0:
            return None  # Cycles: an area light of zero size does not contribute
        radiance = power / (math.pi * area) if normalize else power / math.pi
        # Spread below 180°: Cycles' soft-box grid (the core limits the emission to its cone).
        spread = float(np.clip(np.nan_to_num(light.spread, nan=math.pi), 0.0, math.pi))
        return LightData("area", name, dict(
            matrix=m.astype(np.float32), size_x=size_x, size_y=size_y,
            radiance=tuple(radiance.tolist()), ellipse=ellipse, cast_shadow=cast_shadow,
            spread=spread, **flags, **ies, **shader), images=images)

    warn(f"Light '{name}': light type {light.type} is not supported; skipped")
    return None


def object_lightgroup(instance):
    """Object ▸ Shading ▸ Light Group of a depsgraph instance: the object's, or where it has
    none its instancer's (Cycles' sync_object: b_ob's, else b_parent's). Read from the original
    objects: setting the field tags no depsgraph update, so an evaluated copy made before
    may still hold the old name."""
    def group(obj):
        obj = getattr(obj, "original", None) or obj
        return getattr(obj, "lightgroup", "") or ""
    name = group(instance.object)
    if not name and instance.is_instance and instance.parent is not None:
        name = group(instance.parent)
    return name


def light_max_bounces(light):
    """Cycles' light Max Bounces (light.cycles.max_bounces, 0..1024; 1024 where Cycles' add-on
    is not there to give one)."""
    cycles = getattr(light, "cycles", None)
    try:
        return max(0, min(int(getattr(cycles, "max_bounces", 1024)), 1024))
    except (TypeError, ValueError):
        return 1024


def collect_lights(depsgraph, warn, is_visible):
    """LightData for every visible light instance of the depsgraph (collection instances
    included: each instance carries its own matrix_world)."""
    lights = []
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type != 'LIGHT' or not is_visible(instance):
            continue
        data = convert_light(obj, instance.matrix_world, warn)
        if data is not None:
            data.lightgroup = object_lightgroup(instance)
            data.max_bounces = light_max_bounces(obj.data)
            lights.append(data)
    return lights
