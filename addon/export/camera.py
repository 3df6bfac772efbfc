"""Scene camera → the fields of pc.Camera (Blender's conventions and units, as Cycles reads them)."""

import math

import numpy as np


class ExportError(Exception):
    """The scene cannot be rendered; the message is for the user."""


def camera_params(scene, depsgraph, warn, view=None):
    """Dict of pc.Camera fields for the scene's active camera, or for a render view's camera
    (view: an export.views.ViewCamera, multiview: its object, model matrix, shift and spherical
    stereo)."""
    if view is not None:
        cam_obj = view.camera
        matrix = np.array(view.matrix, np.float32)
    elif scene.camera is None:
        raise ExportError("The scene has no active camera")
    else:
        cam_obj = scene.camera.evaluated_get(depsgraph)
        matrix = np.array(cam_obj.matrix_world, np.float32)
    # Like Cycles, ignore the camera object's scale.
    matrix[:3, :3] /= np.linalg.norm(matrix[:3, :3], axis=0)
    render = scene.render
    params = dict(
        matrix_world=matrix,
        pixel_aspect_x=float(render.pixel_aspect_x),
        pixel_aspect_y=float(render.pixel_aspect_y),
    )
    cam = cam_obj.data
    if cam_obj.type != 'CAMERA':
        return params  # any object can be the camera; Blender then uses the default lens
    cam_type = cam.type
    if cam_type not in ('PERSP', 'ORTHO', 'PANO'):
        warn(f"Camera '{cam_obj.name}': {cam_type.lower()} projection is not supported yet; "
             "rendering with a perspective projection")
        cam_type = 'PERSP'
    params.update(
        type=cam_type,
        lens=cam.lens,
        sensor_width=cam.sensor_width,
        sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit,
        shift_x=cam.shift_x if view is None else view.shift_x,
        shift_y=cam.shift_y,
        clip_start=cam.clip_start,
        clip_end=cam.clip_end,
    )
    if cam_type == 'ORTHO':
        params["ortho_scale"] = cam.ortho_scale
    if cam_type == 'PANO':
        params.update(panorama_params(cam, cam_obj.name, render, warn))
    if view is not None and view.stereo and cam_type in ('PERSP', 'PANO'):
        params.update(view.stereo)
    params.update(_dof_params(cam_obj, cam, cam_type, matrix, depsgraph, warn))
    _autofocus_params(scene, params)
    if params.get("use_autofocus") and "aperture_size" not in params:
        warn(f"Camera '{cam_obj.name}': autofocus needs the camera's depth of field; ignored")
        params["use_autofocus"] = False
    return params


# Blender's defaults (RNA), the fallback for a value that is not finite or out of range.
_PANO_DEFAULTS = dict(fisheye_fov=math.pi, fisheye_lens=10.5, latitude_min=-math.pi / 2,
                      latitude_max=math.pi / 2, longitude_min=-math.pi, longitude_max=math.pi,
                      central_cylindrical_range_u_min=-math.pi, central_cylindrical_range_u_max=math.pi,
                      central_cylindrical_range_v_min=-1.0, central_cylindrical_range_v_max=1.0,
                      central_cylindrical_radius=1.0)
_POLY_DEFAULTS = (-1.1735143743862864e-05, -0.019988736137747765, -3.3525323033245513e-06,
                  3.0992753181635635e-06, -2.60646473293491e-08)
_POSITIVE = ("fisheye_fov", "fisheye_lens", "central_cylindrical_radius")


def panorama_params(cam, name, render, warn):
    """pc.Camera fields of a panoramic camera (Blender's names and units, as Cycles reads them).
    Values that are not finite (or not positive where they must be) fall back to Blender's
    defaults with a warning; ranges that are reversed render as Cycles renders them (mirrored)."""
    ptype = str(cam.panorama_type)
    out = dict(panorama_type=ptype)
    for key, default in _PANO_DEFAULTS.items():
        v = float(getattr(cam, key, default))
        if not math.isfinite(v) or (key in _POSITIVE and not v > 0.0):
            warn(f"Camera '{name}': {key} {v:g} is not usable; using {default:g}")
            v = default
        out[key] = v
    k = [float(getattr(cam, f"fisheye_polynomial_k{i}", d)) for i, d in enumerate(_POLY_DEFAULTS)]
    if not all(math.isfinite(v) for v in k):
        warn(f"Camera '{name}': the fisheye polynomial has a value that is not finite; using "
             "Blender's default coefficients")
        k = list(_POLY_DEFAULTS)
    out["fisheye_polynomial"] = k
    if ptype == 'EQUIRECTANGULAR':
        for a, b in (("latitude_min", "latitude_max"), ("longitude_min", "longitude_max")):
            if out[a] > out[b]:
                warn(f"Camera '{name}': {a} is above {b}; the panorama is mirrored, as in Cycles")
            elif out[a] == out[b]:
                warn(f"Camera '{name}': {a} equals {b}; the panorama has no extent on that axis")
    elif ptype == 'CENTRAL_CYLINDRICAL':
        for a, b in (("central_cylindrical_range_u_min", "central_cylindrical_range_u_max"),
                     ("central_cylindrical_range_v_min", "central_cylindrical_range_v_max")):
            if out[a] == out[b]:
                warn(f"Camera '{name}': {a} equals {b}; the panorama has no extent on that axis")
    elif ptype == 'FISHEYE_LENS_POLYNOMIAL' and not _polynomial_sees(out, cam, render):
        warn(f"Camera '{name}': the lens polynomial maps no pixel inside the field of view; the "
             "image is black, as in Cycles")
    return out


def _polynomial_sees(params, cam, render):
    """Whether some pixel of the frame gets a ray from the lens polynomial (Cycles' test:
    |theta| <= fov / 2), checked on a grid of the fitted sensor."""
    xr = float(render.resolution_x) * float(render.pixel_aspect_x)
    yr = float(render.resolution_y) * float(render.pixel_aspect_y)
    if not (xr > 0 and yr > 0):
        return True
    fit = cam.sensor_fit
    size = float(cam.sensor_height if fit == 'VERTICAL' else cam.sensor_width)
    horizontal = fit == 'HORIZONTAL' or (fit == 'AUTO' and xr > yr)
    w, h = (size, size * yr / xr) if horizontal else (size * xr / yr, size)
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, 65) * w, np.linspace(-0.5, 0.5, 65) * h)
    r = np.hypot(u, v)
    k = params["fisheye_polynomial"]
    with np.errstate(all="ignore"):
        theta = -(k[0] + k[1] * r + k[2] * r**2 + k[3] * r**3 + k[4] * r**4)
        return bool(np.any(np.abs(theta) <= 0.5 * params["fisheye_fov"]))


def _autofocus_params(scene, params):
    props = getattr(scene, "pathlight", None)
    if props is None or not getattr(props, "use_autofocus", False):
        return
    x, y = props.autofocus_point
    ok = all(math.isfinite(v) for v in (x, y))
    params.update(use_autofocus=True,
                  autofocus_x=min(max(float(x), 0.0), 1.0) if ok else 0.5,
                  autofocus_y=min(max(float(y), 0.0), 1.0) if ok else 0.5)


def _dof_params(cam_obj, cam, cam_type, matrix, depsgraph, warn):
    """Thin-lens fields as Cycles' Blender sync computes them: aperture radius from the F-stop
    (focal length in mm read as metres / (2 F), or 1 / (2 F) for orthographic cameras), focus
    distance along the view axis (a focus object's position projected on that axis)."""
    dof = cam.dof
    if not dof.use_dof:
        return {}
    name = cam_obj.name
    fstop = float(dof.aperture_fstop)
    if not (fstop > 0.0 and math.isfinite(fstop)):
        warn(f"Camera '{name}': F-stop {fstop:g} is not positive; rendering without depth of field")
        return {}
    if cam_type == 'ORTHO':
        aperture = 1.0 / (2.0 * fstop)
    else:
        aperture = float(cam.lens) * 1e-3 / (2.0 * fstop)
    if not math.isfinite(aperture) or aperture > 1e6:
        warn(f"Camera '{name}': F-stop {fstop:g} gives an absurd aperture; rendering without depth "
             "of field")
        return {}
    ratio = float(dof.aperture_ratio)
    if not (ratio > 0.0 and math.isfinite(ratio)):
        warn(f"Camera '{name}': aperture ratio {ratio:g} is not positive; using 1")
        ratio = 1.0
    rotation = float(dof.aperture_rotation)
    focus = _focus_distance(cam_obj, dof, matrix, depsgraph, warn)
    if focus is None:
        return {}
    return dict(aperture_size=aperture, focus_distance=focus,
                aperture_blades=int(dof.aperture_blades),
                aperture_rotation=rotation if math.isfinite(rotation) else 0.0,
                aperture_ratio=ratio)


def _focus_distance(cam_obj, dof, matrix, depsgraph, warn):
    """Focus distance along the view axis, or None (with a warning) when there is none."""
    name = cam_obj.name
    target = dof.focus_object
    distance = float(dof.focus_distance)
    if target is not None:
        target_eval = target.evaluated_get(depsgraph)
        position = np.array(target_eval.matrix_world, np.float64)[:3, 3]
        sub = dof.focus_subtarget
        if sub and target_eval.pose is not None:  # a bone: its head, as Cycles
            bone = target_eval.pose.bones.get(sub)
            if bone is not None:
                head = np.array(target_eval.matrix_world, np.float64) @ np.array(bone.matrix, np.float64)
                position = head[:3, 3]
        view_axis = matrix[:3, 2].astype(np.float64)  # local +Z, unit (scale removed)
        depth = abs(float(np.dot(view_axis, matrix[:3, 3] - position)))
        if math.isfinite(depth) and depth > 1e-6:
            return depth
        warn(f"Camera '{name}': focus object '{target.name}' lies in the camera's plane; using the "
             f"focus distance {distance:g} instead")
    if distance > 0.0 and math.isfinite(distance):
        return distance
    warn(f"Camera '{name}': focus distance {distance:g} is not positive; rendering without depth "
         "of field")
    return None
