"""Blender depsgraph → plain numpy/tuple data (`export_scene` → SceneData). Nothing in this
package writes the core scene: addon/scene_writer.py turns SceneData into a pc.Scene, so the
export itself can be tested without the core."""

from dataclasses import dataclass, field

import numpy as np

from .camera import ExportError, camera_params
from .curves import CurvesData, collect_curves
from .light import LightData, collect_lights
from .light_linking import attach_to_lights, light_links
from .material import MaterialData, MaterialTable, view_layer_ids
from .mesh import ExportCancelled, MeshData, collect_meshes, is_visible
from .object_attributes import InstanceAttributes
from .points import PointsData, collect_points
from .view_layer import layer_settings, lit_world
from .volume import collect_volumes
from .world import WorldProgram, WorldSky, WorldTexture, export_world, world_sampled, world_volume

__all__ = ("CurvesData", "ExportCancelled", "ExportError", "LightData", "MaterialData", "MeshData",
           "PointsData", "SceneData", "WorldSky", "WorldTexture", "export_scene")


@dataclass
class SceneData:
    meshes: list  # MeshData
    material_slots: list  # per mesh: list of indices into materials, one per slot
    materials: list  # MaterialData
    world_color: tuple
    camera: dict  # pc.Camera fields
    lights: list = field(default_factory=list)  # LightData
    world_texture: WorldTexture = None  # or a WorldSky; replaces world_color when set
    images: list = field(default_factory=list)  # shader.ImageData the material programs use
    material_names: list = field(default_factory=list)  # per material: the bpy name ("" = none)
    uv_sets: object = None  # shader.UvSets: the global uv-set numbering the programs use
    world_volume: dict = None  # the world's homogeneous medium (add_shader's volume dict) or None
    curves: list = field(default_factory=list)  # CurvesData (hair)
    curve_materials: list = field(default_factory=list)  # per curves: its index into materials
    # Volume objects' grids (pathlight_core.VolumeGrid): grid id k is entry k; their boxes are
    # among `meshes` (export.volume).
    volume_grids: list = field(default_factory=list)
    volume_material_names: frozenset = frozenset()  # materials compiled for volume objects too
    points: list = field(default_factory=list)  # PointsData (point clouds)
    point_materials: list = field(default_factory=list)  # per point cloud: its index into materials
    # Light linking: object name -> (light_set, light_mask, shadow_set, shadow_mask)
    # (export.light_linking); lights carry theirs in LightData.links.
    light_links: dict = field(default_factory=dict)
    # Light groups (View Layer ▸ Light Groups): the view layer's group names in order (the
    # core's group indices); the world's group name (World ▸ Settings ▸ Light Group).
    light_groups: list = field(default_factory=list)
    world_lightgroup: str = ""
    world_program: WorldProgram = None  # a world node tree beyond the fast path's (export.world)
    # World ▸ Settings ▸ Sampling Method: Automatic / Manual (True) or None (False: the world is
    # no light to sample; rays alone find it, as Cycles).
    world_sampled: bool = True


def export_scene(depsgraph, warn, mesh_cache=None, need_camera=True, should_stop=None, uv_pass=False,
                 aovs=(), layer=None, cull_udim_tiles=False):
    """Everything Pathlight renders, read from the evaluated depsgraph. warn(msg) reports
    unsupported features (each call is one message for the user). mesh_cache: a
    mesh_cache.MeshCache that keeps unchanged meshes' arrays between exports (animation).
    need_camera=False: a scene without a camera exports with a default one (the viewport
    renders through its own view). should_stop(): polled between meshes; True raises
    ExportCancelled. uv_pass: every mesh exports its active render UV map for the UV pass
    (data.uv_sets.names.index("") is its uv set). aovs: the view layer's shader AOVs, (name,
    'COLOR' or 'VALUE') in slot order, that AOV Output nodes write. layer: the view layer's
    view_layer.LayerSettings (overrides, filters), read from the depsgraph when None.
    cull_udim_tiles: drop the UDIM tiles that no UV corner of a material's meshes lies in, as
    Cycles' final renders (not its viewport) do (cull_tiles below)."""
    scene = depsgraph.scene
    if layer is None:
        layer = layer_settings(depsgraph)
    world = lit_world(layer)
    camera = camera_params(scene, depsgraph, warn) if need_camera or scene.camera else {}
    table = MaterialTable(warn, getattr(scene.pathlight, "use_schlick_fresnel", False),
                          view_layer_ids(depsgraph), depsgraph)
    attributes = InstanceAttributes(table.uv_sets.object_attributes, scene.frame_current_final)
    table.uv_sets.aovs = {name: (slot, kind) for slot, (name, kind) in enumerate(aovs)}
    if uv_pass:
        table.pass_uv_set = table.uv_sets.index("")
        if table.pass_uv_set is None:
            warn("The UV pass found no free UV map slot (materials read 8); it stays empty")
    meshes = collect_meshes(depsgraph, table.uv_names, mesh_cache, should_stop, attributes, layer)
    # (a mesh without UV map reads 0 in the UV pass, as Cycles, without a warning)
    pass_only = uv_pass and not any("" in m.uv_sets.values() for m in table.materials)
    for mesh in meshes:
        missing = [m for m in mesh.missing_uv_maps if not (pass_only and m == "(active render UV map)")]
        if missing:
            warn(f"Mesh '{mesh.name}' has no UV map {', '.join(map(repr, missing))} "
                 "that its materials use; UV (0, 0) is used")
        if mesh.missing_attributes:
            warn(f"Mesh '{mesh.name}' has no attribute "
                 f"{', '.join(map(repr, mesh.missing_attributes))} that its materials read; 0 is used")
        if getattr(mesh, "tangent_problem", None):
            warn(f"Mesh '{mesh.name}': {mesh.tangent_problem}")
        if getattr(mesh, "subdivision_problem", None):
            warn(f"Object '{mesh.name}': {mesh.subdivision_problem}")
    material_slots = [[table.index(m) for m in mesh.materials] for mesh in meshes]
    volume_grids = table.grids  # (Point Density textures' grids are already there)
    volume_meshes, volume_slots = collect_volumes(depsgraph, warn, table, volume_grids, layer)
    meshes += volume_meshes
    material_slots += volume_slots
    curves = collect_curves(depsgraph, warn, table.index, attributes, table.uv_names, layer)
    curve_materials = [table.index(c.material) for c in curves]
    points = collect_points(depsgraph, warn, table.index, attributes, table.uv_names, layer)
    point_materials = [table.index(p.material) for p in points]
    if cull_udim_tiles:
        cull_tiles(table, meshes, material_slots, set(curve_materials) | set(point_materials))
    lights = collect_lights(depsgraph, warn, is_visible)
    try:
        links = light_links(depsgraph, warn)
    except (AttributeError, TypeError) as e:  # an older or odd Blender: render without linking
        warn(f"Light linking could not be read ({e}); lights reach every object")
        links = {}
    attach_to_lights(lights, links)
    # (Curves and point clouds: receivers, blockers and emitters, scene_writer's _link_sets.)
    far = distance_from_origin(meshes, camera.get("matrix_world", np.eye(4)))
    if far > FAR_FROM_ORIGIN:
        warn(f"The scene lies {far:.3g} units from the world origin: beyond {FAR_FROM_ORIGIN:.0e} "
             "units single-precision hit points lose accuracy (shading and shadows may be off "
             "by a few percent); move the scene closer to the origin")
    w_color, w_texture, w_program = export_world(world, warn, scene.frame_current)
    return SceneData(meshes, material_slots, table.materials,
                     w_color, camera, lights,
                     w_texture, table.images.images,
                     table.material_names(), table.uv_sets, world_volume(world, warn),
                     curves, curve_materials, volume_grids, frozenset(table.volume_material_names),
                     points, point_materials, links, view_layer_lightgroups(getattr(depsgraph, "view_layer", None)),
                     world_lightgroup(world), w_program, world_sampled(world))


def uv_tiles(uv):
    """The UDIM tiles that UV corners `uv` (float32 (..., 2)) lie in, as Cycles'
    Attribute::get_uv_tiles counts them: tile 1001 + int(u) + 10 int(v) (C's truncation) for
    u in (-1, 10) and v > -1, a corner within 1e-6 above a tile's left or lower edge (u or v
    > 1) counting for the tile before it."""
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    uv = uv[np.isfinite(uv).all(axis=1) & (np.abs(uv) < 1e6).all(axis=1)]
    u, v = uv[:, 0], uv[:, 1]
    x, y = np.trunc(u).astype(np.int64), np.trunc(v).astype(np.int64)
    ok = (x >= 0) & (y >= 0) & (x < 10)
    eps = np.float32(1e-6)
    x = np.where((x > 0) & (u < x.astype(np.float32) + eps), x - 1, x)
    y = np.where((y > 0) & (v < y.astype(np.float32) + eps), y - 1, y)
    return set((1001 + 10 * y[ok] + x[ok]).tolist())


def cull_tiles(table, meshes, material_slots, other_materials):
    """Cycles' final renders load, for each Image Texture node of a UDIM image, only the tiles
    that a UV corner of some geometry using the node's material lies in, on the node's UV map
    (ImageTextureNode::cull_tiles: every corner of every mesh whose materials include it,
    whichever faces use it); a lookup in a dropped tile reads magenta. The node's own tile set
    (ImageTable.tile_owners) loses those tiles here. Materials of curves or point clouds keep
    every tile (their UVs are not counted here)."""
    names = list(getattr(table.uv_sets, "names", []))
    for image_index, (material, uv_map) in table.images.tile_owners.items():
        m = table.material_index(material)
        if m is None or m in other_materials or uv_map not in names:
            continue
        k = names.index(uv_map)
        used = set()
        for mesh, slots in zip(meshes, material_slots):
            uv = mesh.uvs.get(k) if m in slots else None
            if uv is not None:
                used |= uv_tiles(uv)
        data = table.images.images[image_index]
        data.tiles = tuple((n, i) for n, i in data.tiles if n in used)


MAX_LIGHT_GROUPS = 64  # the core's kMaxLightGroups


def world_lightgroup(world):
    """World ▸ Settings ▸ Light Group (of the original world: the field tags no depsgraph
    update), "" without a world."""
    if world is None:
        return ""
    world = getattr(world, "original", None) or world
    return getattr(world, "lightgroup", "") or ""


def view_layer_lightgroups(view_layer):
    """The names of a view layer's light groups (View Layer ▸ Light Groups), in order: group i
    is the core's light group i (Cycles numbers them so too). At most MAX_LIGHT_GROUPS."""
    names = [g.name for g in getattr(view_layer, "lightgroups", ()) if g.name]
    return names[:MAX_LIGHT_GROUPS]


# Measured by tests/core/test_robustness_numeric.py: a 2-unit Cornell box stays correct within noise
# when translated 3e4 units, and is off by 3 % at 1e5 (features must exceed ~1e-6 x their
# distance from the origin).
FAR_FROM_ORIGIN = 3e4


def distance_from_origin(meshes, camera_matrix):
    """How far the scene sits from the world origin: the larger of the camera's distance and
    the distance of the centre of the geometry's world bounds (finite vertices only)."""
    far = float(np.linalg.norm(np.asarray(camera_matrix, np.float64)[:3, 3]))
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for mesh in meshes:
        p = mesh.positions
        if not len(p) or not mesh.matrices:
            continue
        # float32 min/max are exact and propagate NaN and inf: only a mesh with non-finite
        # vertices needs the filtered (slower, float64) pass. Column by column: numpy's
        # reduction over axis 0 of an (N, 3) array is ~40x slower (27 ms for 0.5M vertices).
        a = np.array([p[:, k].min() for k in range(3)], np.float64)
        b = np.array([p[:, k].max() for k in range(3)], np.float64)
        if not (np.isfinite(a).all() and np.isfinite(b).all()):
            p = np.asarray(p, np.float64)
            p = p[np.isfinite(p).all(axis=1)]
            if not len(p):
                continue
            a, b = p.min(axis=0), p.max(axis=0)
        # The 8 corners of the local box, through every instance matrix: (I, 8, 3).
        corners = np.array([[(a, b)[i >> k & 1][k] for k in range(3)] for i in range(8)])
        m = np.asarray(mesh.matrices, np.float64)
        world = corners @ m[:, :3, :3].transpose(0, 2, 1) + m[:, None, :3, 3]
        world = world.reshape(-1, 3)
        world = world[np.isfinite(world).all(axis=1)]
        if len(world):
            lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
    if np.all(lo <= hi):
        far = max(far, float(np.linalg.norm((lo + hi) / 2)))
    return far


def mean_radiance(tex):
    """Solid-angle mean of an equirectangular WorldTexture (rows weighted by cos(latitude))."""
    h = tex.pixels.shape[0]
    weights = np.cos((np.arange(h) + 0.5) / h * np.pi - np.pi / 2)
    rows = tex.pixels.mean(axis=1)  # (H, 3)
    return weights @ rows / weights.sum() * tex.strength
