"""The viewport's drawing (addon/viewport_draw.py) without a GPU: the pixel conversion, and the
gpu-module calls recorded by a stand-in for `gpu` / `gpu_extras` (bpy has no GPU context in
background mode: gpu.types.Buffer and GPUTexture raise there)."""

import sys
import types

import bpy
import numpy as np
import pytest

from blender_util import core_has, empty_scene_with_camera, load_addon

from addon import viewport_draw
from addon.viewport_draw import HALF_MAX, draw_film, texture_pixels


class FakeGpu:
    """Records the gpu calls of draw_film in order; the Buffer keeps what it was handed."""

    def __init__(self, calls, fail_draw=False):
        self.calls = calls
        rec = self

        class Buffer:
            def __init__(self, fmt, size, data):
                self.fmt, self.size, self.data = fmt, size, data
                rec.calls.append(("Buffer", fmt, size))

        class GPUTexture:
            def __init__(self, size, format, data):
                self.size, self.format, self.data = size, format, data
                rec.calls.append(("GPUTexture", size, format))

        def blend_set(mode):
            rec.calls.append(("blend_set", mode))

        def draw_texture_2d(texture, position, width, height):
            rec.calls.append(("draw_texture_2d", texture, position, width, height))
            if fail_draw:
                raise RuntimeError("draw failed")

        self.gpu = types.ModuleType("gpu")
        self.gpu.types = types.SimpleNamespace(Buffer=Buffer, GPUTexture=GPUTexture)
        self.gpu.state = types.SimpleNamespace(blend_set=blend_set)
        self.extras = types.ModuleType("gpu_extras")
        self.presets = types.ModuleType("gpu_extras.presets")
        self.presets.draw_texture_2d = draw_texture_2d
        self.extras.presets = self.presets

    def install(self, monkeypatch):
        monkeypatch.setitem(sys.modules, "gpu", self.gpu)
        monkeypatch.setitem(sys.modules, "gpu_extras", self.extras)
        monkeypatch.setitem(sys.modules, "gpu_extras.presets", self.presets)


class FakeEngine:
    """What view_update / view_draw use of a RenderEngine."""

    def __init__(self, calls):
        self.calls = calls
        self.reports = []
        self.redraws = 0

    def bind_display_space_shader(self, scene):
        self.calls.append(("bind_display_space_shader", scene))

    def unbind_display_space_shader(self):
        self.calls.append(("unbind_display_space_shader",))

    def report(self, kind, msg):
        self.reports.append((kind, msg))

    def tag_redraw(self):
        self.redraws += 1


def _film(h=3, w=5):
    rng = np.random.default_rng(1)
    film = rng.uniform(0.0, 4.0, (h, w, 4)).astype(np.float32)
    film[..., 3] = 1.0
    return film


def test_texture_pixels_are_the_scene_linear_film_in_texture_order():
    film = _film()
    film[0, 0, :3] = (0.5, 0.2, 0.01)  # linear mid-grey etc.: an sRGB encode would change them
    film[2, 4, 0] = 1e6  # above the half-float range
    film[1, 2, 1] = -3e5
    out = texture_pixels(film)
    assert out.dtype == np.float32 and out.flags.c_contiguous and out.shape == (3 * 5 * 4,)
    # Row 0 (bottom) first, pixels left to right, RGBA interleaved: GPU texture order, no flip.
    expected = film.copy()
    expected[2, 4, 0] = HALF_MAX
    expected[1, 2, 1] = -HALF_MAX
    np.testing.assert_array_equal(out, expected.reshape(-1))
    assert out[:3].tolist() == pytest.approx([0.5, 0.2, 0.01])  # unchanged: still linear
    assert np.isfinite(out.astype(np.float16)).all()  # fits a half-float texture
    # The array is reused when the size fits, replaced when the region changed.
    assert texture_pixels(film, out) is out
    bigger = texture_pixels(_film(4, 5), out)
    assert bigger is not out and bigger.size == 80
    with pytest.raises(ValueError):
        texture_pixels(np.zeros((3, 5, 3), np.float32))


def test_draw_film_uploads_the_film_and_draws_through_the_display_space_shader(monkeypatch):
    calls = []
    FakeGpu(calls).install(monkeypatch)
    engine, scene = FakeEngine(calls), object()
    film = _film(3, 5)
    pixels = draw_film(engine, scene, film, 20, 12)
    names = [c[0] for c in calls]
    assert names == ["Buffer", "GPUTexture", "blend_set", "bind_display_space_shader",
                     "draw_texture_2d", "unbind_display_space_shader", "blend_set"]
    _, fmt, size = calls[0]
    assert fmt == "FLOAT" and size == 5 * 3 * 4
    _, tex_size, tex_format = calls[1]
    assert tex_size == (5, 3) and tex_format in ("RGBA16F", "RGBA32F")  # (width, height)
    assert calls[2] == ("blend_set", "ALPHA_PREMULT") and calls[-1] == ("blend_set", "NONE")
    assert calls[3] == ("bind_display_space_shader", scene)
    texture = calls[4][1]
    assert calls[4][2:] == ((0, 0), 20, 12)  # stretched over the whole region
    # The Buffer got the contiguous float32 array itself (buffer protocol, no list) holding
    # the film's linear values: nothing converted them on the way.
    data = texture.data.data
    assert data is pixels and isinstance(data, np.ndarray)
    assert data.dtype == np.float32 and data.flags.c_contiguous
    np.testing.assert_array_equal(data, film.reshape(-1))
    # The next draw of the same size reuses the array.
    calls.clear()
    assert draw_film(engine, scene, film, 20, 12, pixels) is pixels


def test_draw_film_unbinds_when_drawing_fails(monkeypatch):
    calls = []
    FakeGpu(calls, fail_draw=True).install(monkeypatch)
    with pytest.raises(RuntimeError):
        draw_film(FakeEngine(calls), object(), _film(), 5, 3)
    assert [c[0] for c in calls][-2:] == ["unbind_display_space_shader", "blend_set"]
    assert calls[-1] == ("blend_set", "NONE")


def _scene():
    load_addon()
    sc = empty_scene_with_camera(16)
    sc.render.engine = "PATHLIGHT"
    mesh = bpy.data.meshes.new("Quad")
    mesh.from_pydata([(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)], [], [(0, 1, 2, 3)])
    quad = bpy.data.objects.new("Quad", mesh)
    sc.collection.objects.link(quad)
    sc.world = bpy.data.worlds.new("W")
    sc.world.use_nodes = True
    sc.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    sc.pathlight.preview_samples = 2
    bpy.context.view_layer.update()
    return sc


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
@pytest.mark.parametrize("perspective", [True, False])
def test_view_update_and_view_draw_draw_the_sessions_film(monkeypatch, perspective):
    """The engine callbacks end to end with a stand-in context and gpu: the region's view
    (perspective, or orthographic since the core has that camera) is rendered, the texture
    gets the session's film, and the engine keeps asking for redraws until it is done."""
    sc = _scene()
    calls = []
    FakeGpu(calls).install(monkeypatch)
    cam = sc.camera
    width, height = 24, 16
    dg = bpy.context.evaluated_depsgraph_get()
    if perspective:
        window = np.array(cam.calc_matrix_camera(dg, x=width, y=height))
    else:
        window = np.zeros((4, 4))
        window[0, 0], window[1, 1], window[2, 2] = 2 / 3.0, 2 / 2.0, -2 / 40.0
        window[2, 3], window[3, 3] = 0.0, 1.0  # near -20, far 20: Blender's free ortho view
    context = types.SimpleNamespace(
        region=types.SimpleNamespace(width=width, height=height),
        region_data=types.SimpleNamespace(view_matrix=np.array(cam.matrix_world.inverted()),
                                          window_matrix=window, is_perspective=perspective))
    engine = FakeEngine(calls)
    viewport_draw.view_update(engine, context, dg)
    vs = engine._pathlight_viewport
    assert vs is not None and not engine.reports
    assert vs._view_camera["type"] == ("PERSP" if perspective else "ORTHO")
    for _ in range(2000):  # bounded, not a timing assertion
        redraws = engine.redraws
        viewport_draw.view_draw(engine, context, dg)
        if engine.redraws == redraws:
            break
        vs.full.wait(0.05) if vs.full is not None else vs.low.wait(0.05)
    else:
        raise AssertionError("the viewport never finished")
    assert not engine.reports
    film, samples = vs.display()
    assert samples == 2 and film.shape == (height, width, 4)
    texture = [c for c in calls if c[0] == "draw_texture_2d"][-1][1]
    assert texture.size == (width, height)
    np.testing.assert_array_equal(texture.data.data, film.reshape(-1))
    assert film[..., :3].max() > 0
    viewport_draw.free(engine)
    assert engine._pathlight_viewport is None
