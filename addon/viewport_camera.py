"""The 3D viewport's view -> pc.Camera fields (pure numpy; no bpy).

The viewport hands us `region_data.view_matrix` (world -> view) and `window_matrix` (the
OpenGL projection of the whole region). Rendering through exactly that projection shows what
the viewport shows, in free navigation and in camera view alike (in camera view the
projection spans the region around the camera frame, passepartout included, with the view's
zoom and offset already in it).

Both projections map to the core's camera with a horizontal sensor fit (sensor width S,
shift, pixel aspect ycor), region width w and height h (P row-major, OpenGL convention).

Perspective, lens L, view plane at depth 1:
    P[0][0] = 2 L / S                      -> L = P[0][0] S / 2
    P[1][1] = P[0][0] * w / (ycor * h)     -> ycor
    P[0][2] = 2 shift_x                    -> shift_x = P[0][2] / 2
    P[1][2] = 2 shift_y w / (ycor h)       -> shift_y
    near = P[2][3] / (P[2][2] - 1), far = P[2][3] / (P[2][2] + 1)

Orthographic, ortho scale O (the view width in world units), view box [l, r] x [b, t]:
    P[0][0] = 2 / (r - l) = 2 / O          -> O = 2 / P[0][0]
    P[1][1] = 2 / (t - b)                  -> ycor = P[0][0] w / (P[1][1] h), as above
    P[0][3] = -(r + l) / (r - l)           -> box centre x = O shift_x: shift_x = -P[0][3] / 2
    P[1][3] = -(t + b) / (t - b)           -> box centre y = O shift_y: shift_y = -P[1][3] P[0][0] / (2 P[1][1])
    near = (P[2][3] + 1) / P[2][2], far = (P[2][3] - 1) / P[2][2]
Blender's free orthographic view clips from -clip_end/2 to +clip_end/2 around the view point
(a negative near plane); the core needs near >= 0, so the camera moves back along its view
axis by -near, which gives the same rays (they are parallel).
"""

import numpy as np

SENSOR = 36.0


class ViewCameraError(ValueError):
    """The view cannot be rendered (a degenerate or non-finite projection)."""


def view_camera_params(view_matrix, window_matrix, width, height, is_perspective=True):
    """Dict of pc.Camera fields that render the region (width x height pixels) as the viewport
    shows it, perspective or orthographic. Raises ViewCameraError for degenerate views."""
    view = np.asarray(view_matrix, np.float64)
    proj = np.asarray(window_matrix, np.float64)
    if not (np.all(np.isfinite(view)) and np.all(np.isfinite(proj))) or width < 1 or height < 1:
        raise ViewCameraError("the view is degenerate")
    # The matrix decides; is_perspective (rv3d.is_perspective) must agree with it.
    ortho = np.allclose(proj[3], (0.0, 0.0, 0.0, 1.0))
    if not ortho and not np.allclose(proj[3], (0.0, 0.0, -1.0, 0.0)):
        raise ViewCameraError("the view's projection is neither perspective nor orthographic")
    if ortho == bool(is_perspective):
        raise ViewCameraError("the view's projection does not match its perspective flag")
    try:
        cam_to_world = np.linalg.inv(view)
    except np.linalg.LinAlgError:
        raise ViewCameraError("the view is degenerate") from None
    cam_to_world[:3, :3] /= np.linalg.norm(cam_to_world[:3, :3], axis=0)  # no scale, as Blender
    p00, p11 = proj[0, 0], proj[1, 1]
    if not (p00 > 0 and p11 > 0):
        raise ViewCameraError("the view's projection is degenerate")
    ycor = p00 * width / (p11 * height)
    fields = dict(sensor_width=SENSOR, sensor_height=SENSOR, sensor_fit="HORIZONTAL",
                  pixel_aspect_x=1.0, pixel_aspect_y=float(ycor))
    if ortho:
        near = (proj[2, 3] + 1.0) / proj[2, 2]
        far = (proj[2, 3] - 1.0) / proj[2, 2]
        if not (np.isfinite(near) and np.isfinite(far) and far > near):
            near, far = -500.0, 500.0
        if near < 0.0:  # move back: the core's near plane is at depth >= 0
            cam_to_world[:3, 3] += cam_to_world[:3, 2] * (-near)
            near, far = 0.0, far - near
        fields.update(type="ORTHO", ortho_scale=float(2.0 / p00),
                      shift_x=float(-proj[0, 3] / 2.0),
                      shift_y=float(-proj[1, 3] * p00 / (2.0 * p11)))
    else:
        near = proj[2, 3] / (proj[2, 2] - 1.0)
        far = proj[2, 3] / (proj[2, 2] + 1.0)
        if not (np.isfinite(near) and np.isfinite(far) and far > near >= 0):
            near, far = 0.01, 1000.0
        fields.update(type="PERSP", lens=float(p00 * SENSOR / 2.0),
                      shift_x=float(proj[0, 2] / 2.0),
                      shift_y=float(proj[1, 2] * ycor * height / (2.0 * width)))
    fields.update(matrix_world=cam_to_world.astype(np.float32), clip_start=float(near),
                  clip_end=float(far))
    return fields


def pano_view_params(camera_fields, frame_world, view_matrix, window_matrix, width, height,
                     render_aspect):
    """A panoramic scene camera seen in the viewport's camera view: the camera's own fields
    (from export.camera.camera_params), with the panorama mapped to the camera border as Cycles
    maps it (its viewplane is the region relative to the border, [0, 1]^2 being the frame).
    frame_world: the camera frame's 4 corners in world space (Camera.view_frame through
    matrix_world); render_aspect: the render's width over height, pixel aspect included (what
    the fisheye sensor is fitted to). The shift adds as in a final render (Cycles' viewport
    scales it by two aspect ratios of the region that are equal). Raises ViewCameraError for
    a degenerate view."""
    view = np.asarray(view_matrix, np.float64)
    proj = np.asarray(window_matrix, np.float64)
    corners = np.asarray(frame_world, np.float64).reshape(-1, 3)
    clip = (proj @ view @ np.c_[corners, np.ones(len(corners))].T).T
    if width < 1 or height < 1 or not np.all(np.isfinite(clip)) or not np.all(clip[:, 3] > 0):
        raise ViewCameraError("the camera border is not in view")
    px = (clip[:, 0] / clip[:, 3] + 1.0) * 0.5 * width
    py = (clip[:, 1] / clip[:, 3] + 1.0) * 0.5 * height
    x0, x1, y0, y1 = px.min(), px.max(), py.min(), py.max()
    if not (x1 - x0 > 1e-6 and y1 - y0 > 1e-6 and np.isfinite(render_aspect) and render_aspect > 0):
        raise ViewCameraError("the camera border is degenerate")
    fields = dict(camera_fields)
    fields.update(pano_viewplane=(float(-x0 / (x1 - x0)), float((width - x0) / (x1 - x0)),
                                  float(-y0 / (y1 - y0)), float((height - y0) / (y1 - y0))),
                  pano_fit_aspect=float(render_aspect))
    return fields
