"""Scene camera → the fields of pc.Camera (Blender's conventions and units)."""

import numpy as np


class ExportError(Exception):
    """The scene cannot be rendered; the message is for the user."""


def camera_params(scene, depsgraph, warn):
    """Dict of pc.Camera fields for the scene's active camera."""
    if scene.camera is None:
        raise ExportError("The scene has no active camera")
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
    if cam.type != 'PERSP':
        warn(f"Camera '{cam_obj.name}': {cam.type.lower()} projection is not supported yet; "
             "rendering with a perspective projection")
    params.update(
        lens=cam.lens,
        sensor_width=cam.sensor_width,
        sensor_height=cam.sensor_height,
        sensor_fit=cam.sensor_fit,
        shift_x=cam.shift_x,
        shift_y=cam.shift_y,
        clip_start=cam.clip_start,
        clip_end=cam.clip_end,
    )
    return params
