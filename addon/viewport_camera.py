"""The 3D viewport's view -> pc.Camera fields (pure numpy; no bpy).

The viewport hands us `region_data.view_matrix` (world -> view) and `window_matrix` (the
OpenGL projection of the whole region). Rendering through exactly that projection shows what
the viewport shows, in free navigation and in camera view alike (in camera view the
projection spans the region around the camera frame, passepartout included).

For a perspective projection P (row-major, OpenGL convention) and the core's camera with a
horizontal sensor fit (sensor width S, lens L, shift, pixel aspect ycor), at view depth 1:
    P[0][0] = 2 L / S                      -> L = P[0][0] S / 2
    P[1][1] = P[0][0] * width / (ycor * height)   -> ycor
    P[0][2] = 2 shift_x                    -> shift_x = P[0][2] / 2
    P[1][2] = 2 shift_y width / (ycor height)     -> shift_y
    near = P[2][3] / (P[2][2] - 1), far = P[2][3] / (P[2][2] + 1)
"""

import numpy as np

SENSOR = 36.0


class ViewCameraError(ValueError):
    """The view cannot be rendered (e.g. orthographic: the core has no orthographic camera)."""


def view_camera_params(view_matrix, window_matrix, width, height, is_perspective=True):
    """Dict of pc.Camera fields that render the region (width x height pixels) as the viewport
    shows it. Raises ViewCameraError for orthographic views."""
    view = np.asarray(view_matrix, np.float64)
    proj = np.asarray(window_matrix, np.float64)
    if not is_perspective or abs(proj[3, 3]) > 1e-9:
        raise ViewCameraError("orthographic views are not supported by Pathlight yet")
    if not (np.all(np.isfinite(view)) and np.all(np.isfinite(proj))) or width < 1 or height < 1:
        raise ViewCameraError("the view is degenerate")
    cam_to_world = np.linalg.inv(view)
    cam_to_world[:3, :3] /= np.linalg.norm(cam_to_world[:3, :3], axis=0)  # no scale, as Blender
    p00, p11 = proj[0, 0], proj[1, 1]
    if not (p00 > 0 and p11 > 0):
        raise ViewCameraError("the view's projection is degenerate")
    ycor = p00 * width / (p11 * height)
    near = proj[2, 3] / (proj[2, 2] - 1.0)
    far = proj[2, 3] / (proj[2, 2] + 1.0)
    if not (np.isfinite(near) and np.isfinite(far) and far > near >= 0):
        near, far = 0.01, 1000.0
    return dict(
        matrix_world=cam_to_world.astype(np.float32),
        lens=float(p00 * SENSOR / 2.0),
        sensor_width=SENSOR,
        sensor_height=SENSOR,
        sensor_fit="HORIZONTAL",
        shift_x=float(proj[0, 2] / 2.0),
        shift_y=float(proj[1, 2] * ycor * height / (2.0 * width)),
        clip_start=float(near),
        clip_end=float(far),
        pixel_aspect_x=1.0,
        pixel_aspect_y=float(ycor),
    )
