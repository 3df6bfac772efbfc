"""Keeps exported mesh arrays between renders, so that an animation re-exports only the
meshes whose evaluated geometry changed from frame to frame.

Blender gives a fresh engine and a fresh depsgraph for every frame of an animation unless
render.use_persistent_data is on (checked in bpy 4.5: without it, depsgraph.updates lists
every ID as updated on every frame), so the depsgraph cannot say what changed. The cache
therefore keys an entry on the mesh datablock and its material slots, and checks it with a
fingerprint of the evaluated mesh: positions, topology (corner vertices, face sizes), every
generic attribute (UV maps, material indices, sharp faces/edges, ...) and custom normals.
Reading those with foreach_get costs a fraction of an export (no triangulation, no normal
computation, no per-corner gathers). Entries not used by an export are dropped at its end,
so the cache holds at most one scene's meshes.

With persistent data and one view layer, the final render's depsgraph outlives the render and
depsgraph.updates lists exactly what changed since the last render (checked in bpy 4.5: a moved
camera lists only the camera's transform; an edited mesh, a modifier, a geometry-nodes input or
an animated modifier on a new frame list the object's geometry; a fresh depsgraph lists every
ID). Such a render is "tracked": an entry of the last tracked export of the same depsgraph is
reused, without a fingerprint and without evaluating the mesh, when neither its object nor
the object's mesh is listed as changed, as Cycles trusts the same list. Tracked exports compute
no fingerprints (~30 ms for a 1M-triangle mesh); any other export compares fingerprints, so an
entry without one never serves it.

Geometry that geometry nodes generate as instances has its instancer as `original` (and the
instancer's mesh as `original.data`): its key adds its ordinal among the instancer's generated
geometries in the depsgraph's order, else one key would stand for the instancer's own mesh and
every generated one. The order holds while the instancer is not re-evaluated (tracked exports
re-export all of them when it is listed as changed; fingerprints check the rest).
"""

import dataclasses
import hashlib
import logging

import numpy as np

from .tangents import tangent_uv_maps

log = logging.getLogger(__name__)

# foreach_get field of each attribute data type.
_FIELDS = {"FLOAT": "value", "INT": "value", "BOOLEAN": "value", "INT8": "value",
           "FLOAT_VECTOR": "vector", "FLOAT2": "vector", "INT32_2D": "value",
           "FLOAT_COLOR": "color", "BYTE_COLOR": "color", "QUATERNION": "value",
           "FLOAT4X4": "value"}
_WIDTH = {"FLOAT_VECTOR": 3, "FLOAT2": 2, "INT32_2D": 2, "FLOAT_COLOR": 4, "BYTE_COLOR": 4,
          "QUATERNION": 4, "FLOAT4X4": 16}


# Attributes that only the editor's UI uses (selection): they cannot change a render.
_UI_ONLY = (".select_vert", ".select_edge", ".select_poly")


def mesh_fingerprint(mesh):
    """A digest of everything of a bpy Mesh that the export reads.

    Only raw-array reads (attributes, the face of each loop triangle): the per-element
    collections vertices.co, loops.vertex_index and polygons.loop_total took 0.22 s of a
    1M-triangle mesh's 0.41 s fingerprint and hold nothing the "position" and ".corner_vert"
    attributes and the triangles' faces do not (a face of k corners has k - 2 triangles).
    Each array is hashed by the core's XXH64 (5 ms for 36 MB, where BLAKE2b took 65 ms), the
    names, sizes and those hashes by BLAKE2b."""
    from ..core import get_core
    hash_buffer = get_core().hash_buffer
    h = hashlib.blake2b(digest_size=16)

    def add(collection, name, dtype, width=1):
        a = np.empty(len(collection) * width, dtype)
        collection.foreach_get(name, a)
        h.update(np.array([a.nbytes, hash_buffer(a)], np.uint64).tobytes())

    h.update(np.array([len(mesh.vertices), len(mesh.loops), len(mesh.polygons)], np.int64).tobytes())
    names = {attr.name for attr in mesh.attributes}
    if "position" not in names:
        add(mesh.vertices, "co", np.float32, 3)
    if ".corner_vert" not in names:
        add(mesh.loops, "vertex_index", np.int32)
    mesh.calc_loop_triangles()
    add(mesh.loop_triangle_polygons, "value", np.int32)
    for attr in sorted(mesh.attributes, key=lambda a: a.name):
        if attr.name in _UI_ONLY:
            continue
        field = _FIELDS.get(attr.data_type)
        if field is None:
            h.update(f"{attr.name}:{attr.data_type}:unknown".encode())
            continue
        h.update(f"{attr.name}:{attr.data_type}:{attr.domain}".encode())
        dtype = np.float32 if attr.data_type.startswith(("FLOAT", "BYTE", "QUAT")) else np.int32
        add(attr.data, field, dtype, _WIDTH.get(attr.data_type, 1))
    if mesh.has_custom_normals:
        add(mesh.corner_normals, "vector", np.float32, 3)
    return h.digest()


def changed_ids(depsgraph):
    """The original IDs (as_pointer) whose geometry depsgraph.updates lists as updated (only
    objects and their meshes are looked up). Transforms and shading (a material edit lists its
    objects and meshes with shading updates only) leave the mesh arrays as they were."""
    return {u.id.original.as_pointer() for u in depsgraph.updates if u.is_updated_geometry}


class MeshCache:
    """export(obj, materials, uv_names) with the signature of mesh._export_object, served
    from the cache when the evaluated mesh is unchanged. Counts hits and misses."""

    def __init__(self):
        self._entries = {}  # key -> (fingerprint or None (tracked), MeshData without matrices)
        self._used = set()
        self._token = None  # the depsgraph (pointer, scene, view layer) of the last tracked export
        self._next_token = None  # this export's, set as _token once it ends
        self._changed = None  # a trusted export: the original IDs the depsgraph lists as changed
        self.hits = self.misses = 0
        self.current = self._new_stats()  # of the export in progress
        self.previous = None  # of the last finished export: {hits, misses, hit, missed}

    def clear(self):
        self._entries.clear()
        self._used.clear()
        self._token = self._next_token = self._changed = None

    def begin_export(self, depsgraph, tracked):
        """Call first in every render that uses the cache, before anything can fail: the
        depsgraph's updates of this render are read here or never (a render that fails before
        its export ends leaves no token, so the next one compares fingerprints or exports).
        tracked: the depsgraph is the final render's with persistent data and one view layer."""
        previous, self._token, self._next_token, self._changed = self._token, None, None, None
        token = None
        if tracked:
            token = (depsgraph.as_pointer(), depsgraph.scene.name, depsgraph.view_layer.name)
        self._changed = changed_ids(depsgraph) if tracked and token == previous else None
        self._next_token = token

    def export(self, obj, materials, uv_names=None, generated=0):
        """generated: for geometry that geometry nodes made for an instance, its ordinal (from
        1) among its instancer's in this export; 0 for an object's own geometry."""
        from .mesh import mesh_data  # noqa: avoid an import cycle at module load
        key = self._key(obj, materials, uv_names) + (generated,)
        self._used.add(key)
        entry = self._entries.get(key)
        if entry is not None and self._changed is not None and not self._is_changed(obj):
            return self._hit(obj, entry, materials)
        # One evaluated mesh for the fingerprint and, on a miss, the export (its triangulation
        # and normals caches are then warm).
        mesh = obj.to_mesh()
        try:
            fingerprint = None
            if mesh is not None and self._next_token is None:  # tracked exports need none
                fingerprint = mesh_fingerprint(mesh)
            if entry is not None and fingerprint is not None and entry[0] == fingerprint:
                return self._hit(obj, entry, materials)
            self._count("misses", obj)
            data = mesh_data(obj, mesh, materials, uv_names)
        finally:
            obj.to_mesh_clear()
        if fingerprint is not None or self._next_token is not None:
            self._entries[key] = (fingerprint, data)
        return data

    def _hit(self, obj, entry, materials):
        self._count("hits", obj)
        data = entry[1]
        if data is None:
            return None
        # Fresh instance list and the slots' materials of this export; arrays are shared
        # (nothing modifies them after export).
        return dataclasses.replace(data, materials=list(materials) or data.materials, matrices=[])

    def _count(self, what, obj):
        setattr(self, what, getattr(self, what) + 1)
        self.current[what] += 1
        self.current["hit" if what == "hits" else "missed"].append(obj.original.name)

    def _is_changed(self, obj):
        original = obj.original
        data = original.data
        return (original.as_pointer() in self._changed or
                (data is not None and data.as_pointer() in self._changed))

    def end_export(self):
        """Drops the entries the export did not use; logs and resets the per-export counts."""
        for key in list(self._entries):
            if key not in self._used:
                del self._entries[key]
        self._used.clear()
        self._token, self._next_token, self._changed = self._next_token, None, None
        done = self.current
        log.info("mesh export cache: %d hit(s), %d miss(es)", done["hits"], done["misses"])
        self.current = self._new_stats()
        self.previous = done

    @staticmethod
    def _new_stats():
        return {"hits": 0, "misses": 0, "hit": [], "missed": []}

    @staticmethod
    def _key(obj, materials, uv_names):
        original = obj.original
        data = original.data
        uv = tuple(sorted(uv_names(materials).items())) if uv_names else ()
        if uv:  # the UV maps whose tangents are exported follow the materials' node trees
            uv += (tangent_uv_maps(materials),)
        # Objects with modifiers evaluate to their own geometry even when sharing a mesh.
        owner = original.name if len(original.modifiers) else ""
        return (data.as_pointer() if data is not None else 0, data.name if data else "", owner,
                tuple(m.name if m else "" for m in materials), uv)
