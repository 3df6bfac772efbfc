"""Motion blur: the camera's and the objects' transforms at the shutter's motion steps, read by
evaluating the depsgraph at sub-frames as Cycles' Blender sync does (RenderEngine.frame_set),
and Blender's shutter curve as the values Cycles samples from it."""

import math

import numpy as np

RAMP_TABLE_SIZE = 256  # Cycles samples the shutter curve at this many evenly spaced times
MAX_STEPS_SETTING = 7  # Blender's motion_steps range is 1..7 (2^(steps - 1) * 2 + 1 steps)


def motion_step_count(obj):
    """Cycles' object_motion_steps: an odd number of steps, one at the frame, 2^(steps-1) either side."""
    cyc = getattr(obj, "cycles", None)
    steps = int(getattr(cyc, "motion_steps", 1)) if cyc is not None else 1
    steps = min(max(steps, 1), MAX_STEPS_SETTING)
    return (2 << (steps - 1)) + 1


def uses_deform_motion(obj):
    cyc = getattr(obj, "cycles", None)
    return bool(getattr(cyc, "use_deform_motion", True)) if cyc is not None else True


def may_deform(obj, scene):
    """Whether obj's evaluated mesh may change over the shutter (deforming modifiers, shape
    keys, geometry nodes): only those are evaluated at every step."""
    try:
        if obj.is_deform_modified(scene, 'RENDER'):
            return True
    except (AttributeError, TypeError, RuntimeError):
        return True
    keys = getattr(obj.data, "shape_keys", None)
    if keys is not None and keys.animation_data is not None:
        return True
    return any(m.type == 'NODES' for m in obj.modifiers)


def uses_motion_blur(obj):
    cyc = getattr(obj, "cycles", None)
    return bool(getattr(cyc, "use_motion_blur", True)) if cyc is not None else True


def relative_times(count):
    """The steps' times in -1..1 of the half shutter (Cycles' motion_time)."""
    return [-1.0 + 2.0 * i / (count - 1) for i in range(count)]


def shutter_curve(render):
    """Blender's shutter curve as Cycles reads it: RAMP_TABLE_SIZE values at i / (size - 1)."""
    mapping = getattr(render, "motion_blur_shutter_curve", None)
    if mapping is None:
        return []
    try:
        mapping.update()
        curve = mapping.curves[0]
        values = [float(mapping.evaluate(curve, i / (RAMP_TABLE_SIZE - 1))) for i in range(RAMP_TABLE_SIZE)]
    except (AttributeError, IndexError, RuntimeError):
        return []
    return [v if math.isfinite(v) else 0.0 for v in values]


def instance_key(instance):
    """What names one depsgraph object instance across sub-frames."""
    obj = instance.object
    if instance.is_instance:
        parent = instance.parent.original.name if instance.parent is not None else ""
        return (obj.original.name, parent, tuple(instance.persistent_id))
    return (obj.original.name, "", ())


def usable_steps(steps):
    """Whether (S, 4, 4) steps are finite and invertible (what the core can interpolate)."""
    if not np.isfinite(steps).all():
        return False
    det = np.linalg.det(steps[:, :3, :3].astype(np.float64))
    scale = np.abs(steps[:, :3, :3].astype(np.float64)).max(axis=(1, 2)) ** 3
    return bool(np.all(np.abs(det) > 1e-12 * scale))


def _object(scene, name):
    """The original object named `name`: the scene's, or one only instanced into it."""
    obj = scene.objects.get(name)
    if obj is None:
        import bpy  # objects of instanced collections need not be in the scene
        obj = bpy.data.objects.get(name)
    return obj


def _positions(obj_eval):
    """float32 (V, 3) vertex positions of an evaluated object's mesh, or None."""
    from .mesh import mesh_positions
    try:
        mesh = obj_eval.to_mesh()
        return None if mesh is None else mesh_positions(mesh).copy()
    finally:
        obj_eval.to_mesh_clear()


def read_velocity(data, n):
    """A curves' or point cloud's 'velocity' attribute (POINT, FLOAT_VECTOR; units per second)
    as float32 (N, 3), or None: Cycles' deformation blur from velocity (it then exports no
    sub-frames for that geometry)."""
    attr = data.attributes.get("velocity") if getattr(data, "attributes", None) is not None else None
    if attr is None or attr.domain != 'POINT' or attr.data_type != 'FLOAT_VECTOR' or n == 0:
        return None
    v = np.empty(n * 3, np.float32)
    try:
        attr.data.foreach_get("vector", v)
    except (RuntimeError, TypeError):
        return None
    return v.reshape(-1, 3)


def _deform_arrays(instance, entry, render):
    """(points, radii) of a curves or point cloud entry's geometry at the current sub-frame,
    read from its depsgraph instance, or None. render: a final render's depsgraph (particle
    hair's render or viewport counts, as its export read them)."""
    obj = instance.object
    if getattr(entry, "psys_key", None) is not None:  # particle hair: its keys again (co_hair)
        from .curves import _particle_hair
        for key, _material, arrays, _uvs in _particle_hair(obj, render, lambda msg: None):
            if key == entry.psys_key:
                return arrays[0], arrays[2]
        return None
    if obj.type == 'CURVES':
        from .curves import curve_points_radii
        return curve_points_radii(obj.data)
    if obj.type == 'POINTCLOUD':
        from .points import cloud_points_radii
        return cloud_points_radii(obj.data)
    return None


def _kind(entry):
    return "strands" if hasattr(entry, "offsets") else "points"


def camera_matrix(obj):
    m = np.array(obj.matrix_world, np.float32)
    m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)  # Blender ignores the camera's scale
    return m


def rolling_shutter(scene):
    """pc.Camera fields of Cycles' Rolling Shutter (Render ▸ Motion Blur, under Cycles' names in
    scene.pathlight): {} where it is off."""
    settings = getattr(scene, "pathlight", None)
    if getattr(settings, "rolling_shutter_type", 'NONE') != 'TOP':
        return {}
    d = float(settings.rolling_shutter_duration)
    return {"rolling_shutter": True, "rolling_shutter_duration": min(max(d, 0.0), 1.0) if math.isfinite(d) else 0.0}


def add_motion(engine, depsgraph, data, warn, cameras=()):
    """Fills SceneData `data` (exported at the current frame) with motion blur: data.camera's
    "motion" and "shutter_curve", and each MeshData's `motions` (per matrix: (S, 4, 4) steps or
    None). Evaluates the depsgraph at the sub-frames (engine.frame_set) and restores the frame.
    cameras: other camera objects (Multi-View's views) whose steps go to
    data.camera_motions[name]. Returns the number of moving objects."""
    scene = depsgraph.scene
    render = scene.render
    shutter = float(render.motion_blur_shutter)
    if not (math.isfinite(shutter) and shutter > 0.0):
        warn(f"Motion blur: shutter {shutter:g} is not positive; rendering without motion blur")
        return 0
    frame, subframe = scene.frame_current, float(scene.frame_subframe)
    position = render.motion_blur_position
    fps = float(render.fps) / float(render.fps_base) if render.fps_base else 0.0
    for mesh in data.meshes:  # volume objects' velocity grids
        if getattr(mesh, "volume_velocity", None):
            from .volume import apply_velocity
            apply_velocity(mesh, shutter, fps, position, warn)
    delta = shutter * 0.5 if position == 'START' else -shutter * 0.5 if position == 'END' else 0.0
    # Per instance (a matrix of some MeshData): its step count, or 0 when it does not blur.
    wanted = {}
    counts = set()
    shaped = list(getattr(data, "curves", [])) + list(getattr(data, "points", []))
    movable = list(data.meshes) + shaped
    for mesh in movable:
        for key in getattr(mesh, "motion_keys", []):
            obj = _object(scene, key[0])
            n = motion_step_count(obj) if obj is not None and uses_motion_blur(obj) else 0
            wanted[key] = n
            if n:
                counts.add(n)
    # Deformation blur: single-user meshes of plain objects that may deform.
    deforming = {}  # key -> MeshData
    for mesh in data.meshes:
        keys = getattr(mesh, "motion_keys", [])
        if len(mesh.matrices) != 1 or len(keys) != 1 or keys[0][1] or not wanted.get(keys[0]):
            continue
        obj = _object(scene, keys[0][0])
        if obj is not None and obj.type == 'MESH' and uses_deform_motion(obj) and may_deform(obj, scene):
            deforming[keys[0]] = mesh
    # Deformation blur of curves and point clouds (Cycles' motion keys / points): from their
    # 'velocity' attribute (3 steps, no sub-frames) or read at every step of objects that may
    # deform.
    shaped_deform = {}  # id(entry) -> (entry, key, steps)
    hdt = shutter * 0.5 / fps if fps > 0.0 else 0.0
    for entry in shaped:
        keys = getattr(entry, "motion_keys", [])
        if not keys or not wanted.get(keys[0]):
            continue
        obj = _object(scene, keys[0][0])
        if obj is None or not uses_deform_motion(obj):
            continue
        velocity = getattr(entry, "velocity", None)
        if velocity is not None:
            if not np.isfinite(velocity).all():
                warn(f"Object '{keys[0][0]}': its velocity attribute has NaN or infinite values; "
                     "rendered without deformation blur")
                continue
            if not velocity.any() or hdt == 0.0:
                continue
            # Cycles: the frame's points -+ velocity x half the shutter in seconds, radii as they are.
            p = entry.points.astype(np.float32)
            entry.motion_points = np.stack([p - velocity * hdt, p, p + velocity * hdt]).astype(np.float32)
            entry.motion_radii = None
            continue
        if may_deform(obj, scene):  # (particle hair: its emitter; as Cycles' is_deform_modified)
            shaped_deform[id(entry)] = (entry, keys[0], wanted[keys[0]])
    shaped_at = {}  # (id(entry), relative time) -> (points, radii) or None
    final = getattr(depsgraph, "mode", 'RENDER') == 'RENDER'
    positions = {}  # (key, relative time) -> (V, 3) or None
    cam_obj = scene.camera
    cam_steps = motion_step_count(cam_obj) if cam_obj is not None and uses_motion_blur(cam_obj) else 0
    if cam_steps:
        counts.add(cam_steps)
    others = {c.name: (c, motion_step_count(c)) for c in cameras
              if c is not None and (cam_obj is None or c.name != cam_obj.name) and uses_motion_blur(c)}
    counts.update(n for _, n in others.values())
    other_at = {}
    times = sorted({t for n in counts for t in relative_times(n)})
    if not times:
        return 0
    matrices = {}  # (key, relative time) -> matrix
    cam_at = {}
    try:
        for rel in times:
            t = frame + subframe + delta + rel * shutter * 0.5
            f = math.floor(t)
            engine.frame_set(int(f), t - f)
            if cam_steps and cam_obj is not None:
                cam_at[rel] = camera_matrix(cam_obj.evaluated_get(depsgraph))
            for name, (c, _n) in others.items():
                other_at[(name, rel)] = camera_matrix(c.evaluated_get(depsgraph))
            deform_keys = {}  # (an emitter's hair systems with several materials share its key)
            for e, key, _n in shaped_deform.values():
                deform_keys.setdefault(key, []).append(e)
            for instance in depsgraph.object_instances:
                if instance.object.type not in ('MESH', 'VOLUME', 'POINTCLOUD', 'CURVES'):
                    continue
                key = instance_key(instance)
                if wanted.get(key):
                    matrices[(key, rel)] = np.array(instance.matrix_world, np.float32)
                for entry in deform_keys.pop(key, ()):
                    shaped_at[(id(entry), rel)] = _deform_arrays(instance, entry, final)
            for key, mesh in deforming.items():
                positions[(key, rel)] = _positions(_object(scene, key[0]).evaluated_get(depsgraph))
    finally:
        engine.frame_set(frame, subframe)

    moving = 0
    warned = set()
    for mesh in movable:
        keys = getattr(mesh, "motion_keys", [])
        mesh.motions = [None] * len(mesh.matrices)
        for k, key in enumerate(keys[:len(mesh.matrices)]):
            n = wanted.get(key, 0)
            if not n:
                continue
            steps = [matrices.get((key, rel)) for rel in relative_times(n)]
            if any(s is None for s in steps):
                continue  # not there at every step (appears or vanishes in the shutter): no blur
            steps = np.stack(steps)
            if not usable_steps(steps):
                if key[0] not in warned:
                    warned.add(key[0])
                    warn(f"Object '{key[0]}': its motion over the shutter has NaN, infinite or "
                         "singular (zero-scale) transforms; rendered without motion blur")
                continue
            if not (steps == steps[0]).all():
                mesh.motions[k] = steps
                moving += 1
    for key, mesh in deforming.items():
        steps = [positions.get((key, rel)) for rel in relative_times(wanted[key])]
        n = len(mesh.positions)
        if any(s is None or len(s) != n for s in steps):
            warn(f"Object '{key[0]}': its mesh changes topology over the shutter; rendered "
                 "without deformation blur")
            continue
        steps = np.stack(steps)
        if not np.isfinite(steps).all():
            warn(f"Object '{key[0]}': its deformation over the shutter has NaN or infinite "
                 "positions; rendered without deformation blur")
            continue
        if not (steps == steps[0]).all():
            mesh.motion_positions = steps
            moving += 1
    for entry, key, n in shaped_deform.values():
        steps = [shaped_at.get((id(entry), rel)) for rel in relative_times(n)]
        count = len(entry.points)
        if any(s is None or len(s[0]) != count or len(s[1]) != count for s in steps):
            warn(f"Object '{key[0]}': its {_kind(entry)} change their number of points over the "
                 "shutter; rendered without deformation blur")
            continue
        points = np.stack([s[0] for s in steps]).astype(np.float32)
        radii = np.stack([s[1] for s in steps]).astype(np.float32)
        if not (np.isfinite(points).all() and np.isfinite(radii).all()):
            warn(f"Object '{key[0]}': the deformation of its {_kind(entry)} over the shutter has NaN "
                 "or infinite values; rendered without deformation blur")
            continue
        # Cycles keeps motion only where a step differs from the frame (particle hair: by more
        # than 1e-5, its keys being carried through the emitter's matrices).
        eps = 1e-5 if getattr(entry, "psys_key", None) is not None else 0.0
        if np.abs(points - entry.points).max(initial=0.0) > eps or np.abs(radii - entry.radii).max(initial=0.0) > eps:
            entry.motion_points, entry.motion_radii = points, radii
            moving += 1
    for entry in shaped:
        if getattr(entry, "motion_points", None) is not None and id(entry) not in shaped_deform:
            moving += 1  # (from velocity)
    if cam_steps:
        steps = np.stack([cam_at[rel] for rel in relative_times(cam_steps)])
        if not usable_steps(steps):
            warn(f"Camera '{cam_obj.name}': its motion over the shutter has NaN, infinite or "
                 "singular transforms; rendered without camera motion blur")
        elif not (steps == steps[0]).all():
            data.camera["motion"] = steps
            moving += 1
    for name, (c, n) in others.items():
        steps = np.stack([other_at[(name, rel)] for rel in relative_times(n)])
        if usable_steps(steps) and not (steps == steps[0]).all():
            data.camera_motions = dict(getattr(data, "camera_motions", {}), **{name: steps})
            moving += 1
    if moving:
        data.camera["shutter_curve"] = shutter_curve(render)
        data.camera.update(rolling_shutter(scene))
    return moving


def add_pass_motion(engine, depsgraph, data, warn, cameras=()):
    """The Vector pass's motion, as Cycles' without motion blur (its MOTION_PASS: the depsgraph
    at the frames before and after, frame -+ 1): data.camera["pass_motion"] (2, 4, 4), each
    MeshData's, CurvesData's and PointsData's `pass_motions` (per matrix: (2, 4, 4) or None),
    for single-user meshes that may deform `pass_positions` ((2, V, 3) or None), and for
    curves and point clouds that may deform `pass_points` ((2, N, 3) or None; from their
    'velocity' attribute where they have one, as Cycles). Evaluates the depsgraph at those
    frames and restores the frame. Returns the number of moving objects and cameras."""
    scene = depsgraph.scene
    frame, subframe = scene.frame_current, float(scene.frame_subframe)
    where = {}  # instance key -> [(MeshData, matrix index)]
    deforming = {}  # key -> MeshData
    for mesh in data.meshes:
        keys = getattr(mesh, "motion_keys", [])
        mesh.pass_motions = [None] * len(mesh.matrices)
        mesh.pass_positions = None
        for k, key in enumerate(keys[:len(mesh.matrices)]):
            where.setdefault(key, []).append((mesh, k))
        if len(mesh.matrices) == 1 and len(keys) == 1 and not keys[0][1]:
            obj = _object(scene, keys[0][0])
            if obj is not None and obj.type == 'MESH' and may_deform(obj, scene):
                deforming[keys[0]] = mesh
    shaped_deform = {}  # key -> [CurvesData / PointsData]: read again at those frames
    fps = scene.render.fps / scene.render.fps_base if scene.render.fps_base else 0.0
    for entry in list(getattr(data, "curves", [])) + list(getattr(data, "points", [])):
        entry.pass_motions = [None] * len(entry.matrices)
        entry.pass_points = None
        keys = getattr(entry, "motion_keys", [])
        for k, key in enumerate(keys[:len(entry.matrices)]):
            where.setdefault(key, []).append((entry, k))
        obj = _object(scene, keys[0][0]) if keys else None
        if obj is None:
            continue
        velocity = getattr(entry, "velocity", None)
        if velocity is not None:  # Cycles: the frame's points -+ velocity x a frame in seconds
            if np.isfinite(velocity).all() and velocity.any() and fps > 0.0:
                p = entry.points.astype(np.float32)
                entry.pass_points = np.stack([p - velocity / fps, p + velocity / fps]).astype(np.float32)
        elif may_deform(obj, scene):
            shaped_deform.setdefault(keys[0], []).append(entry)
    cam_obj = scene.camera
    matrices, positions, cam_at, shaped_at = {}, {}, {}, {}
    others = [c for c in cameras if c is not None and (cam_obj is None or c.name != cam_obj.name)]
    final = getattr(depsgraph, "mode", 'RENDER') == 'RENDER'
    try:
        for rel in (-1, 1):
            t = frame + subframe + rel
            f = math.floor(t)
            engine.frame_set(int(f), t - f)
            if cam_obj is not None:
                cam_at[rel] = camera_matrix(cam_obj.evaluated_get(depsgraph))
            for c in others:
                cam_at[(c.name, rel)] = camera_matrix(c.evaluated_get(depsgraph))
            for instance in depsgraph.object_instances:
                key = instance_key(instance)
                if key in where:
                    matrices[(key, rel)] = np.array(instance.matrix_world, np.float32)
                for entry in shaped_deform.get(key, ()):
                    if (id(entry), rel) not in shaped_at:
                        shaped_at[(id(entry), rel)] = _deform_arrays(instance, entry, final)
            for key, mesh in deforming.items():
                positions[(key, rel)] = _positions(_object(scene, key[0]).evaluated_get(depsgraph))
    finally:
        engine.frame_set(frame, subframe)
    moving = 0
    for key, entries in where.items():
        steps = [matrices.get((key, rel)) for rel in (-1, 1)]
        for mesh, k in entries:
            # (not there at one of the frames: still, as Cycles keeps an object it cannot match)
            if any(s is None for s in steps) or not usable_steps(np.stack(steps)):
                continue
            steps_k = np.stack(steps)
            if not (steps_k == np.asarray(mesh.matrices[k], np.float32)).all():
                mesh.pass_motions[k] = steps_k
                moving += 1
    for key, mesh in deforming.items():
        steps = [positions.get((key, rel)) for rel in (-1, 1)]
        n = len(mesh.positions)
        if any(s is None or len(s) != n for s in steps):
            warn(f"Object '{key[0]}': its mesh changes topology between frames; the Vector pass "
                 "leaves out its deformation")
            continue
        steps = np.stack(steps).astype(np.float32)
        if np.isfinite(steps).all() and not (steps == mesh.positions).all():
            mesh.pass_positions = steps
            moving += 1
    for key, entries in shaped_deform.items():
        for entry in entries:
            steps = [shaped_at.get((id(entry), rel)) for rel in (-1, 1)]
            count = len(entry.points)
            if any(s is None or len(s[0]) != count for s in steps):
                warn(f"Object '{key[0]}': its {_kind(entry)} change their number of points between "
                     "frames; the Vector pass leaves out their deformation")
                continue
            points = np.stack([s[0] for s in steps]).astype(np.float32)
            if np.isfinite(points).all() and not (points == entry.points).all():
                entry.pass_points = points
    moving += sum(getattr(e, "pass_points", None) is not None
                  for e in list(getattr(data, "curves", [])) + list(getattr(data, "points", [])))
    if cam_obj is not None:
        steps = np.stack([cam_at[-1], cam_at[1]])
        if np.isfinite(steps).all() and not (steps == data.camera.get("matrix_world", steps[0])).all():
            data.camera["pass_motion"] = steps
            moving += 1
    for c in others:  # Multi-View's other cameras: data.camera_pass_motions[name]
        steps = np.stack([cam_at[(c.name, -1)], cam_at[(c.name, 1)]])
        if np.isfinite(steps).all() and not (steps == camera_matrix(c.evaluated_get(depsgraph))).all():
            data.camera_pass_motions = dict(getattr(data, "camera_pass_motions", {}), **{c.name: steps})
            moving += 1
    return moving
