"""Blender depsgraph → plain numpy/tuple data (`export_scene`), and that data → core objects
(`to_core`). Only `to_core` touches the core module, which it is given, so the export itself
can be tested without the core."""

from dataclasses import dataclass, field

import numpy as np

from .camera import ExportError, camera_params
from .curves import CurvesData, add_curves, collect_curves
from .light import LightData, collect_lights
from .material import MaterialData, MaterialTable, add_materials
from .mesh import ExportCancelled, MeshData, collect_meshes, is_visible
from .world import WorldSky, WorldTexture, world_color, world_texture, world_volume

__all__ = ("CurvesData", "ExportCancelled", "ExportError", "add_lights", "replace_lights", "set_camera", "set_world", "LightData", "MaterialData", "MeshData", "SceneData", "WorldSky", "WorldTexture",
           "export_scene", "to_core")


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


def export_scene(depsgraph, warn, mesh_cache=None, need_camera=True, should_stop=None):
    """Everything Pathlight renders, read from the evaluated depsgraph. warn(msg) reports
    unsupported features (each call is one message for the user). mesh_cache: a
    mesh_cache.MeshCache that keeps unchanged meshes' arrays between exports (animation).
    need_camera=False: a scene without a camera exports with a default one (the viewport
    renders through its own view). should_stop(): polled between meshes; True raises
    ExportCancelled."""
    scene = depsgraph.scene
    camera = camera_params(scene, depsgraph, warn) if need_camera or scene.camera else {}
    table = MaterialTable(warn, getattr(scene.pathlight, "use_schlick_fresnel", False))
    meshes = collect_meshes(depsgraph, table.uv_names, mesh_cache, should_stop)
    for mesh in meshes:
        if mesh.missing_uv_maps:
            warn(f"Mesh '{mesh.name}' has no UV map {', '.join(map(repr, mesh.missing_uv_maps))} "
                 "that its materials use; UV (0, 0) is used")
        if mesh.missing_attributes:
            warn(f"Mesh '{mesh.name}' has no attribute "
                 f"{', '.join(map(repr, mesh.missing_attributes))} that its materials read; 0 is used")
    material_slots = [[table.index(m) for m in mesh.materials] for mesh in meshes]
    curves = collect_curves(depsgraph, warn)
    curve_materials = [table.index(c.material) for c in curves]
    lights = collect_lights(depsgraph, warn, is_visible)
    far = distance_from_origin(meshes, camera.get("matrix_world", np.eye(4)))
    if far > FAR_FROM_ORIGIN:
        warn(f"The scene lies {far:.3g} units from the world origin: beyond {FAR_FROM_ORIGIN:.0e} "
             "units single-precision hit points lose accuracy (shading and shadows may be off "
             "by a few percent); move the scene closer to the origin")
    return SceneData(meshes, material_slots, table.materials,
                     world_color(scene.world, warn), camera, lights,
                     world_texture(scene.world, warn), table.images.images,
                     table.material_names(), table.uv_sets, world_volume(scene.world, warn),
                     curves, curve_materials)


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


def to_core(pc, data, warn=None, material_ids=None, image_ids=None):
    """A pc.Scene (not committed) holding SceneData `data`. warn(msg) hears about what this
    build of the core cannot do. material_ids, image_ids: lists that receive the core id of
    each of data.materials and data.images (for live edits and reuse)."""
    warn = warn if warn is not None else (lambda msg: None)
    scene = pc.Scene()
    ids = add_materials(scene, data.materials, data.images, warn, image_ids)
    if material_ids is not None:
        material_ids.extend(ids)
    for mesh, slots in zip(data.meshes, data.material_slots):
        uvs = {"uvs": mesh.uvs} if mesh.uvs else {}
        if mesh.attributes:
            uvs["attributes"] = mesh.attributes
        if mesh.texspace is not None:
            uvs["texspace"] = mesh.texspace
        mesh_id = scene.add_mesh(mesh.positions, mesh.triangles,
                                 normals=mesh.normals, normal_indices=mesh.normal_indices,
                                 material_indices=mesh.material_indices,
                                 material_slots=[ids[i] for i in slots], **uvs)
        infos = mesh.infos if len(mesh.infos) == len(mesh.matrices) else [None] * len(mesh.matrices)
        names = [name for name, _ in mesh.owners] if len(mesh.owners) == len(mesh.matrices) else None
        deform = getattr(mesh, "motion_positions", None)
        if deform is not None:
            scene.set_mesh_motion(mesh_id, deform)
        motions = getattr(mesh, "motions", None) or []
        for k, (matrix, info) in enumerate(zip(mesh.matrices, infos)):
            # Motion blur steps only where the object moves (and so never for older cores).
            motion = {"motion": motions[k]} if k < len(motions) and motions[k] is not None else {}
            if info is None:
                scene.add_instance(mesh_id, matrix, **motion)
                continue
            color, pass_index, random_id = info
            if random_id is None:
                random_id = pc.object_random_id(names[k]) if names else 0
            scene.add_instance(mesh_id, matrix, color=color, pass_index=pass_index, random_id=random_id, **motion)
    curves = getattr(data, "curves", [])
    if curves:
        mats = iter(data.curve_materials)
        add_curves(scene, curves, lambda _material: ids[next(mats)], warn,
                   getattr(pc, "object_random_id", None))
    add_lights(scene, data.lights, warn)
    set_world(scene, data, warn)
    set_camera(pc, scene, data.camera)
    return scene


def set_camera(pc, scene, params):
    """Sets the camera of a core scene from pc.Camera fields `params`."""
    camera = pc.Camera()
    for name, value in params.items():
        setattr(camera, name, value)
    scene.set_camera(camera)


def add_lights(scene, lights, warn):
    """Adds LightData `lights` to a core scene."""
    for light in lights:
        add = getattr(scene, f"add_{light.kind}_light", None)
        if add is None:  # an older core build
            warn(f"{light.kind.capitalize()} lights are not supported by this build of the "
                 "Pathlight core; ignored")
            continue
        add(**light.args)


def replace_lights(scene, lights, world, warn):
    """Replaces a committed core scene's lights (LightData) and world (`world`: what set_world
    reads of SceneData); its next commit() rebuilds only the light distribution."""
    scene.clear_lights()
    add_lights(scene, lights, warn)
    set_world(scene, world, warn)


def set_world(scene, data, warn):
    """Sets the world (texture or colour) of SceneData `data` on a core scene."""
    tex = data.world_texture
    if isinstance(tex, WorldSky):
        setter = getattr(scene, f"set_world_{'sky' if tex.kind == 'nishita' else tex.kind}")
        setter(strength=tex.strength, rotation=tex.rotation, **tex.params)
    elif tex is not None:
        scene.set_world_texture(tex.pixels, tex.strength, tex.rotation)
    else:
        scene.set_world_color(data.world_color)
    volume = getattr(data, "world_volume", None)
    scene.set_world_volume(volume)
