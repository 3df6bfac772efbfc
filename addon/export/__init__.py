"""Blender depsgraph → plain numpy/tuple data (`export_scene`), and that data → core objects
(`to_core`). Only `to_core` touches the core module, which it is given, so the export itself
can be tested without the core."""

from dataclasses import dataclass

from .camera import ExportError, camera_params
from .material import MaterialData, MaterialTable
from .mesh import MeshData, collect_meshes
from .world import world_color

__all__ = ("ExportError", "MaterialData", "MeshData", "SceneData", "export_scene", "to_core")


@dataclass
class SceneData:
    meshes: list  # MeshData
    material_slots: list  # per mesh: list of indices into materials, one per slot
    materials: list  # MaterialData
    world_color: tuple
    camera: dict  # pc.Camera fields


def export_scene(depsgraph, warn):
    """Everything Pathlight renders, read from the evaluated depsgraph. warn(msg) reports
    unsupported features (each call is one message for the user)."""
    scene = depsgraph.scene
    camera = camera_params(scene, depsgraph, warn)
    meshes = collect_meshes(depsgraph)
    table = MaterialTable(warn)
    material_slots = [[table.index(m) for m in mesh.materials] for mesh in meshes]

    n_lights = sum(1 for obj in depsgraph.objects if obj.type == 'LIGHT')
    if n_lights:
        warn(f"{n_lights} light object(s) ignored: Pathlight renders only emissive meshes "
             "and the world for now")
    return SceneData(meshes, material_slots, table.materials,
                     world_color(scene.world, warn), camera)


def to_core(pc, data):
    """A pc.Scene (not committed) holding SceneData `data`."""
    scene = pc.Scene()
    ids = [scene.add_material(m.name, base_color=m.base_color, emission=m.emission)
           for m in data.materials]
    for mesh, slots in zip(data.meshes, data.material_slots):
        mesh_id = scene.add_mesh(mesh.positions, mesh.triangles,
                                 corner_normals=mesh.corner_normals,
                                 material_indices=mesh.material_indices,
                                 material_slots=[ids[i] for i in slots])
        for matrix in mesh.matrices:
            scene.add_instance(mesh_id, matrix)
    scene.set_world_color(data.world_color)
    camera = pc.Camera()
    for name, value in data.camera.items():
        setattr(camera, name, value)
    scene.set_camera(camera)
    return scene
