"""Multi-view renders (Output > Stereoscopy): the views of a render and each view's camera, read
through Blender's RenderEngine API as Cycles' BlenderSession::render and sync_camera read them.

- The views are those of the render result (Cycles: the views of a 1x1 result): 'left' and
  'right' for Stereo 3D, the enabled views for Multi-View; [""] without multiview.
- Per view, engine.active_view_set(name) makes Blender's camera functions answer for that view:
  engine.camera_override is the view's camera object (Multi-View: the camera whose name has the
  view's suffix), engine.camera_model_matrix holds the eye's offset and toe-in,
  engine.camera_shift_x the off-axis shift. With spherical stereo (engine.use_spherical_stereo)
  both give the centre camera and the core offsets every ray itself (CameraDesc.stereo_eye).
- Each view after the first renders with its own seed (Cycles: different noise per view).
"""

import math
from dataclasses import dataclass, field

import numpy as np

from .camera import ExportError


@dataclass
class ViewCamera:
    name: str  # the render view ('left', 'right', or a Multi-View name)
    camera: object  # the view's evaluated camera object
    matrix: np.ndarray  # (4, 4) float64: its model matrix for this view (scale removed)
    shift_x: float  # its horizontal shift for this view (off-axis stereo adds to it)
    stereo: dict = field(default_factory=dict)  # pc.Camera spherical stereo fields, or {}
    # matrix = camera's scale-free matrix_world @ local: the view's offset from its camera
    # object, which that camera's motion-blur and Vector-pass steps take too
    local: np.ndarray = None


def view_names(engine, scene, layer):
    """The views this render's result has, in order; [""] without multiview."""
    if not scene.render.use_multiview or engine.is_preview:
        return [""]
    result = engine.begin_result(0, 0, 1, 1, layer=layer)
    try:
        names = [v.name for v in result.views]
    finally:
        engine.end_result(result, cancel=True)
    return names or [""]


def _scale_free(m):
    m = np.array(m, np.float64)
    m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
    return m


def view_camera(engine, scene, depsgraph, name):
    """The ViewCamera of render view `name` (engine.active_view_set is left at that view)."""
    engine.active_view_set(name)
    cam = engine.camera_override  # Blender's RE_GetCamera for this view, evaluated
    if cam is None:
        if scene.camera is None:
            raise ExportError("The scene has no active camera")
        cam = scene.camera.evaluated_get(depsgraph)
    if cam.type != 'CAMERA':
        # (Blender's stereo functions read the object's data as a camera: not for a lamp or an
        # empty looking through the scene; such a view renders as the object sees.)
        return ViewCamera(name, cam, _scale_free(cam.matrix_world), 0.0, local=np.eye(4))
    spherical = bool(engine.use_spherical_stereo(cam)) and cam.data.type != 'ORTHO'
    matrix = _scale_free(engine.camera_model_matrix(cam, use_spherical_stereo=spherical))
    shift_x = float(engine.camera_shift_x(cam, use_spherical_stereo=spherical))
    stereo = {}
    if spherical and name in ("left", "right"):
        st = cam.data.stereo
        conv = float(st.convergence_distance)
        stereo = dict(stereo_eye=name.upper(),
                      interocular_distance=float(st.interocular_distance),
                      convergence_distance=math.inf if st.convergence_mode == 'PARALLEL' else conv,
                      use_pole_merge=bool(st.use_pole_merge),
                      pole_merge_angle_from=float(st.pole_merge_angle_from),
                      pole_merge_angle_to=float(st.pole_merge_angle_to))
    local = np.linalg.inv(_scale_free(cam.matrix_world)) @ matrix
    return ViewCamera(name, cam, matrix, shift_x, stereo, local)


def view_motion(steps, view):
    """Steps (S, 4, 4) of the view's camera object (motion blur, Vector pass) moved by the
    view's offset from it."""
    return (np.asarray(steps, np.float64) @ view.local).astype(np.float32)


def view_seed(seed, index):
    """The seed of view `index`: the render's for the first, decorrelated for the others (as
    Cycles' seed += hash_uint2(seed, hash_uint2(index * 0xdeadbeef, 0)); kept within the
    core's 31-bit range)."""
    if index == 0:
        return int(seed)
    s = int(seed) & 0xFFFFFFFF
    from ..core import get_core
    h = get_core().hash_uint2
    return (s + h(s, h((index * 0xdeadbeef) & 0xFFFFFFFF, 0))) % (1 << 31)
