"""Volume objects (OpenVDB grids, issue 23) → a box mesh per volume holding a heterogeneous
medium whose program reads the grids (docs/design/volumes.md "Volume objects").

Each evaluated Volume is read by the core's OpenVDB reader from its file: the file itself when
the volume is file-backed and unmodified, else the evaluated grids saved to a temporary file
(geometry nodes, Volume Displace, ...). The grids go into SceneData.volume_grids (their index
is the core's grid id); the object becomes a MeshData box around its grids' active voxels (plus
the trilinear footprint) whose one material is the object's material compiled for these grids."""

import math
import os
import tempfile

import numpy as np

from .mesh import MeshData, is_visible, object_info
from .motion import instance_key, uses_motion_blur

# Parsed files by (path, mtime, size): re-renders and animations whose frame keeps the file
# read it once. A few entries: grids can be large.
_FILE_CACHE = {}
_FILE_CACHE_SIZE = 4

# Unit cube corners and outward (counter-clockwise) triangles.
_CORNERS = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], np.float64)
_BOX_TRIS = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                      [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]], np.int32)


def _core():
    from ..core import get_core
    return get_core()


def read_grids(path, warn, what):
    """{name: grid dict of pathlight_core.read_vdb} of a .vdb file, cached by path and mtime;
    None (with a warning) where the file cannot be read."""
    try:
        st = os.stat(path)
    except OSError as e:
        warn(f"{what}: the volume file '{path}' cannot be read ({e.strerror}); not rendered")
        return None
    key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    grids = _FILE_CACHE.get(key)
    if grids is None:
        grids = _parse(path, warn, what)
        if grids is None:
            return None
        if len(_FILE_CACHE) >= _FILE_CACHE_SIZE:
            _FILE_CACHE.pop(next(iter(_FILE_CACHE)))
        _FILE_CACHE[key] = grids
    return grids


def _parse(path, warn, what):
    try:
        return {g["name"]: g for g in _core().read_vdb(path)}
    except Exception as e:  # the reader's RuntimeError on a bad file, or anything: never raise
        warn(f"{what}: the volume file '{path}' could not be read ({e}); not rendered")
        return None


def volume_file_grids(obj, warn):
    """The grids of evaluated volume object `obj` (read_grids), or None."""
    vol = obj.data
    what = f"Volume '{obj.original.name}'"
    grids = vol.grids
    try:
        loaded = grids.load()
    except RuntimeError:
        loaded = False
    if not loaded and len(grids) == 0:
        msg = grids.error_message or "no grids"
        warn(f"{what}: {msg}; not rendered")
        return None
    if len(grids) == 0:
        return {}
    # File-backed and unmodified: the file as it is (the grids are the file's).
    path = grids.frame_filepath
    unmodified = not any(m.show_render for m in obj.original.modifiers)
    if path and unmodified:
        import bpy
        path = bpy.path.abspath(path, library=vol.library)
        if os.path.isfile(path):
            return read_grids(path, warn, what)
    fd, tmp = tempfile.mkstemp(suffix=".vdb", prefix="pathlight_")
    os.close(fd)
    try:
        try:
            saved = grids.save(tmp)
        except Exception:  # (bpy raises on some failures, returns False on others)
            saved = False
        if not saved:
            warn(f"{what}: its grids could not be saved for rendering ({grids.error_message}); "
                 "not rendered")
            return None
        return _parse(tmp, warn, what)  # (not cached: the evaluated grids change freely)
    finally:
        try:
            os.remove(tmp)
        except OSError:
            pass


def grid_box(grid, clipping=0.0):
    """Object-space (lo, hi) of a VolumeGrid's active voxels and their trilinear footprint, or
    None when it has no active voxel. clipping: the volume's render.clipping; bricks whose
    majorant (which bounds their voxels and their neighbours') is at most that are left out
    of the box, as Cycles leaves voxels below it out of its mesh (ours: to within a brick)."""
    lo, hi = np.array(grid.bbox_min, np.float64), np.array(grid.bbox_max, np.float64)
    if grid.active_voxels == 0 or np.any(lo > hi):
        return None
    if clipping > 0.0:
        origin, block, cells = grid.majorant_grid()
        above = np.argwhere(cells > clipping)  # [z, y, x]
        if not len(above):
            return None
        c_lo, c_hi = above.min(axis=0)[::-1], above.max(axis=0)[::-1]
        lo = np.maximum(lo, np.asarray(origin, np.float64) + c_lo * block)
        hi = np.minimum(hi, np.asarray(origin, np.float64) + (c_hi + 1) * block - 1)
        if np.any(lo > hi):
            return None
    # Voxel i's value sits at index i + 0.5 in Cycles' lookups (the core's too): the trilinear
    # footprint is [min - 0.5, max + 1.5], and half a voxel more for rounding.
    lo, hi = lo - 1.0, hi + 2.0
    corners = lo + _CORNERS * (hi - lo)
    m = np.asarray(grid.transform, np.float64)
    p = corners @ m[:3, :3].T + m[:3, 3]
    return p.min(axis=0), p.max(axis=0)


def box_mesh(name, lo, hi, material):
    positions = (lo + _CORNERS * (hi - lo)).astype(np.float32)
    tris = _BOX_TRIS.copy()
    normals = np.zeros((1, 3), np.float32)  # (a volume boundary is a pass-through surface)
    normals[0, 2] = 1.0
    return MeshData(name, positions, tris, normals, np.zeros_like(tris),
                    np.zeros(len(tris), np.int32), [material])


def collect_volumes(depsgraph, warn, table, grid_list, layer=None):
    """(MeshData boxes, their material slot lists) of the visible volume objects; their grids
    are appended to grid_list (core VolumeGrid objects; the index is the grid id).
    table: the export's MaterialTable (volume_index compiles a material for the grids).
    layer: the view layer's view_layer.LayerSettings (from the depsgraph when None): its
    Volumes filter and Material Override (which volume objects take too, as in Cycles)."""
    from .view_layer import layer_settings
    if layer is None:
        layer = layer_settings(depsgraph)
    if not layer.use_volumes:  # Filter ▸ Volumes off: Cycles syncs volumes without grids
        return [], []
    entries = {}
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type != 'VOLUME' or not is_visible(instance):
            continue
        mat = layer.material_override if layer.material_override is not None else volume_material(obj)
        scale = density_scale(obj.data, instance.matrix_world)
        key = (obj.data.as_pointer(), mat.as_pointer() if mat else 0, round(scale, 6))
        if key not in entries:
            entries[key] = _volume_entry(obj, mat, warn, table, grid_list, scale)
        entry = entries[key]
        if entry is None:
            continue
        mesh = entry[0]
        mesh.matrices.append(np.array(instance.matrix_world, np.float32))
        mesh.owners.append((obj.name, bool(instance.is_instance)))
        mesh.infos.append(object_info(instance, getattr(depsgraph, "view_layer", None)))
        mesh.motion_keys.append(instance_key(instance))
    out = [e for e in entries.values() if e is not None]
    return [e[0] for e in out], [e[1] for e in out]


def volume_material(obj):
    """The material of volume object `obj` (its first slot; geometry nodes' volumes without
    materials keep the original object's, as Blender renders them)."""
    if len(obj.material_slots) and obj.material_slots[0].material is not None:
        return obj.material_slots[0].material
    return None  # Cycles' default volume shader (default_volume_material)


def density_scale(vol, matrix_world):
    """Cycles' object_volume_density: with the volume's Space 'OBJECT' (the default), densities
    are per object-space length: scaled by 1 / |M (1, 1, 1) / sqrt(3)| (M the object's 3x3)."""
    if getattr(vol.render, "space", 'OBJECT') != 'OBJECT':
        return 1.0
    m = np.asarray(matrix_world, np.float64)[:3, :3]
    n = float(np.linalg.norm(m @ np.full(3, 1.0 / np.sqrt(3.0))))
    return 1.0 / n if np.isfinite(n) and n > 0.0 else 1.0


def _volume_entry(obj, mat, warn, table, grid_list, scale=1.0):
    what = f"Volume '{obj.original.name}'"
    if mat is not None and (not mat.use_nodes or mat.node_tree is None):
        return None  # no volume shader: Cycles renders nothing
    parsed = volume_file_grids(obj, warn)
    if not parsed:
        if parsed is not None:
            warn(f"{what}: it has no grids; not rendered")
        return None
    grids = {}  # name -> (grid id, channels)
    boxes = []
    for name, info in parsed.items():
        g = info.get("grid")
        if g is None:
            warn(f"{what}: grid '{name}' is not read ({info.get('skipped') or 'unsupported'}); "
                 "it reads 0")
            continue
        # One core grid per grid read (volumes sharing a file share its grids).
        k = next((i for i, x in enumerate(grid_list) if x is g), None)
        if k is None:
            k = len(grid_list)
            grid_list.append(g)
        grids[name] = (k, int(g.channels))
        box = grid_box(g, max(float(getattr(obj.data.render, "clipping", 0.0)), 0.0))
        if box is not None:
            boxes.append(box)
    if not boxes:
        warn(f"{what}: its grids have no active voxels (above its Clipping); not rendered")
        return None
    index = table.volume_index(mat, grids, scale) if mat is not None else table.default_volume(grids, scale)
    if table.materials[index].volume is None:
        return None  # the material has no Volume
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        warn(f"{what}: its grid transforms are not finite; not rendered")
        return None
    mesh = box_mesh(obj.original.name, lo, hi, mat)
    mesh.volume_velocity = velocity_source(obj, mat, parsed, grids, what)
    return mesh, [index]


def velocity_source(obj, mat, parsed, grids, what):
    """The velocity grids of volume object `obj` for motion blur, as Cycles' sync finds them:
    the vector grid named by the volume's Velocity Grid (or "velocity"), else three float grids
    (velocity_x/y/z, or the volume's velocity_x/y/z_grid names) that Cycles merges. A dict
    (grid ids, largest |component|, voxel size, the volume's velocity settings, or `problem`:
    why it cannot be used), or None when the volume has no velocity."""
    vol = obj.data
    info = {"what": what, "scale": float(getattr(vol, "velocity_scale", 1.0)),
            "unit": getattr(vol, "velocity_unit", 'FRAME'), "use_motion_blur": uses_motion_blur(obj),
            "interpolation": getattr(getattr(mat, "cycles", None), "volume_interpolation", 'LINEAR')
            if mat is not None else 'LINEAR', "problem": None}
    named = getattr(vol, "velocity_grid", "") or ""
    chosen = None
    for name in dict.fromkeys(n for n in (named, "velocity") if n):
        if name not in parsed:
            continue
        g = parsed[name].get("grid")
        if g is None or name not in grids or g.channels != 3:
            info["problem"] = f"its velocity grid '{name}' is not a vector grid"
            return info
        chosen = [name]
        break
    if chosen is None:
        axes = []
        for a in "xyz":
            cands = [getattr(vol, f"velocity_{a}_grid", "") or "", f"velocity_{a}"]
            name = next((n for n in cands if n and n in grids and grids[n][1] == 1), None)
            axes.append(name)
        if all(axes):
            chosen = axes
    if chosen is None:
        if named and named != "velocity":
            info["problem"] = f"it has no velocity grid '{named}'"
            return info
        return None
    gs = [parsed[n]["grid"] for n in chosen]
    if any(g.nonfinite_replaced for g in gs):
        info["problem"] = "its velocity grid has NaN or infinite values"
        return info
    m = np.abs(np.asarray(gs[0].transform, np.float64)[:3, :3])
    info["ids"] = [grids[n][0] for n in chosen]
    info["max"] = max(max(float(v) for v in g.max_abs[:g.channels]) for g in gs)
    info["voxel"] = float(np.linalg.norm(m, axis=0).max())
    info["step"] = m.sum(axis=1)  # object-space extent of one index step along each axis
    return info


def apply_velocity(mesh, shutter, fps, position, warn):
    """Velocity blur of a volume box `mesh` under the shutter (Cycles 4.5: the lookup moves
    back by velocity x scale x (time - offset), scale per frame; a 'SECOND' unit is scaled by
    shutter / fps, and only for objects with motion blur); pads the box by the largest
    displacement in whole voxels as Cycles pads its volume mesh. Sets mesh.velocity."""
    info = mesh.volume_velocity
    mesh.velocity = None
    if not info:
        return
    if info["problem"]:
        warn(f"{info['what']}: {info['problem']}; rendered without velocity blur")
        return
    scale = info["scale"]
    if info["unit"] == 'SECOND':
        scale *= shutter / fps if info["use_motion_blur"] and fps > 0 else 0.0
    if not (np.isfinite(scale) and scale != 0.0 and np.isfinite(info["max"])):
        return
    # Cycles' time: the ray's in [0, 1] over the shutter; a centred shutter subtracts 0.5, one
    # ending on the frame adds 1 - shutter (its kernel's formula).
    offset = -0.5 if position == 'CENTER' else (1.0 - shutter) if position == 'END' else 0.0
    if info["voxel"] > 0.0:
        pad = math.ceil(info["max"] * abs(scale) / info["voxel"])
        grow = pad * np.asarray(info["step"], np.float64)
        lo = mesh.positions.min(axis=0) - grow
        hi = mesh.positions.max(axis=0) + grow
        if np.isfinite(lo).all() and np.isfinite(hi).all():
            mesh.positions = (lo + _CORNERS * (hi - lo)).astype(np.float32)
    interp = info["interpolation"] if info["interpolation"] in ('LINEAR', 'CUBIC', 'CLOSEST') else 'LINEAR'
    mesh.velocity = (tuple(info["ids"]), float(scale), float(offset), interp)
