"""Render passes, transparent film, exposure, the compositor's Denoise node, multilayer EXR
output and the BVH debug view through headless Blender (issue 5)."""
import logging
import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import OpenEXR
import pytest

from blender_util import core_available, core_has, empty_scene_with_camera, load_addon, node_material, read_exr, \
    render_multilayer_file, render_to_array, Warnings
from light_scenes import world_color

addon = load_addon()
from addon import session  # noqa: E402
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402

pytestmark = pytest.mark.skipif(not core_has("Session", "film_pass"), reason="core without render passes")

RES = 32
COLOR = (0.2, 0.5, 0.8)        # the diffuse wall
EMISSION = (4.0, 2.0, 1.0)     # the small lamp in front of it
WORLD = (0.25, 0.5, 0.75)
PASSES = {"Depth": "Z", "Normal": "XYZ", "Position": "XYZ", "Emit": "RGB", "Env": "RGB",
          "Denoising Normal": "XYZ", "Denoising Albedo": "RGB", "Sample Count": "X"}


def quad_object(name, half, y, material):
    """A square of side 2*half in the plane y = const, facing the camera at (0, -6, 0)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-half, y, -half), (half, y, -half), (half, y, half), (-half, y, half)], [], [(0, 1, 2, 3)])
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def wall_scene():
    """Camera at (0, -6, 0) looking along +y (50 mm lens, 36 mm sensor): a diffuse wall at y = 0
    covering exactly the middle 16x16 of 32x32 pixels, a lamp at y = -1 covering the middle
    6x6, and the world around them."""
    sc = empty_scene_with_camera(RES)
    half_view = 6.0 * 18.0 / 50.0  # half the view width at distance 6
    quad_object("Wall", half_view / 2, 0.0, node_material("Wall", "ShaderNodeBsdfDiffuse", Color=(*COLOR, 1)))
    lamp = node_material("Lamp", "ShaderNodeEmission", Color=(*EMISSION, 1), Strength=1.0)
    quad_object("Lamp", 5.0 * 18.0 / 50.0 * 6 / 32, -1.0, lamp)
    world_color(WORLD)
    return sc


def render_multilayer(sc, path, samples=4, **props):
    """Renders with Blender's own file output as a multilayer EXR and reads every channel back:
    {"<pass>.<channel>": float32 (H, W)}, row 0 = top."""
    sc.render.engine = 'PATHLIGHT'
    sc.pathlight.samples = samples
    sc.pathlight.use_adaptive_sampling = False
    # The 1-pixel box filter, as render_to_array's default: the masks below are one pixel in
    # from each edge (the add-on's default is now Blackman-Harris 1.5 px, as Cycles').
    props = {"filter_type": 'BOX', "filter_width": 1.0, **props}
    for key, value in props.items():
        setattr(sc.pathlight, key, value)
    return render_multilayer_file(sc, path)


def enable_all_passes(view_layer):
    view_layer.use_pass_z = view_layer.use_pass_normal = view_layer.use_pass_position = True
    view_layer.use_pass_emit = view_layer.use_pass_environment = True
    view_layer.pathlight.use_pass_denoising_data = True
    view_layer.pathlight.use_pass_sample_count = True


def test_compositor_sockets_follow_the_view_layer():
    sc = wall_scene()
    sc.render.engine = 'PATHLIGHT'
    sc.use_nodes = True
    rl = sc.node_tree.nodes.new("CompositorNodeRLayers")
    names = lambda: {s.name for s in rl.outputs if s.enabled}  # noqa: E731
    assert "Denoising Albedo" not in names() and "Sample Count" not in names()
    enable_all_passes(sc.view_layers[0])
    sc.pathlight.debug_view = 'BVH'
    rl.update()
    assert set(PASSES) | {"BVH Nodes", "BVH Triangles", "Image", "Alpha"} <= names()


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_multilayer_exr_with_every_pass(tmp_path):
    sc = wall_scene()
    enable_all_passes(sc.view_layers[0])
    ch = render_multilayer(sc, tmp_path / "passes.exr", samples=3)
    expected = {"Combined." + c for c in "RGBA"} | {f"{p}.{c}" for p, cs in PASSES.items() for c in cs}
    assert set(ch) == expected
    assert all(v.shape == (RES, RES) for v in ch.values())

    # Masks from the geometry, one pixel in from each edge (edge pixels mix coverage).
    idx = np.arange(RES)
    inner = lambda lo, hi: np.outer((idx > lo) & (idx < hi), (idx > lo) & (idx < hi))  # noqa: E731
    lamp = inner(13, 18)
    wall = inner(8, 23) & ~inner(12, 19)
    world = ~inner(6, 25)

    depth = ch["Depth.Z"]
    np.testing.assert_allclose(depth[wall], 6.0, rtol=1e-5)   # Z along the view axis
    np.testing.assert_allclose(depth[lamp], 5.0, rtol=1e-5)
    np.testing.assert_array_equal(depth[world], 1e10)        # Cycles' value for "nothing"
    normal = np.stack([ch["Normal." + c] for c in "XYZ"], -1)
    np.testing.assert_allclose(normal[wall | lamp], np.broadcast_to([0, -1, 0], normal[wall | lamp].shape), atol=1e-5)
    np.testing.assert_array_equal(normal[world], 0.0)
    pos = np.stack([ch["Position." + c] for c in "XYZ"], -1)
    np.testing.assert_allclose(pos[wall][:, 1], 0.0, atol=1e-5)
    np.testing.assert_allclose(pos[lamp][:, 1], -1.0, atol=1e-5)
    assert np.all(np.diff(pos[wall.any(1)][:, wall.any(0), 2], axis=0) < 0)  # row 0 = top: z falls
    emit = np.stack([ch["Emit." + c] for c in "RGB"], -1)
    np.testing.assert_allclose(emit[lamp], np.broadcast_to(EMISSION, emit[lamp].shape), rtol=1e-5)
    np.testing.assert_array_equal(emit[wall | world], 0.0)
    env = np.stack([ch["Env." + c] for c in "RGB"], -1)
    np.testing.assert_allclose(env[world], np.broadcast_to(WORLD, env[world].shape), rtol=1e-5)
    np.testing.assert_array_equal(env[wall | lamp], 0.0)
    albedo = np.stack([ch["Denoising Albedo." + c] for c in "RGB"], -1)
    np.testing.assert_allclose(albedo[wall], np.broadcast_to(COLOR, albedo[wall].shape), rtol=1e-5)
    dn = np.stack([ch["Denoising Normal." + c] for c in "XYZ"], -1)
    np.testing.assert_allclose(dn[wall], np.broadcast_to([0, 0, -1], dn[wall].shape), atol=1e-5)
    np.testing.assert_array_equal(ch["Sample Count.X"], 3.0)
    combined = np.stack([ch["Combined." + c] for c in "RGB"], -1)
    np.testing.assert_allclose(combined[world], env[world], rtol=1e-5)
    np.testing.assert_allclose(combined[lamp], emit[lamp], rtol=1e-5)


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_transparent_film_and_exposure():
    sc = empty_scene_with_camera(RES)
    half_view = 6.0 * 18.0 / 50.0
    # The middle half of the rows: on the left an opaque wall, on the right a wall that is 30 %
    # Transparent BSDF; the top and bottom quarters show the world.
    mat = node_material("Half", "ShaderNodeMixShader", Fac=0.3)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    diffuse, transparent = nodes.new("ShaderNodeBsdfDiffuse"), nodes.new("ShaderNodeBsdfTransparent")
    mix = next(n for n in nodes if n.bl_idname == "ShaderNodeMixShader")
    links.new(diffuse.outputs[0], mix.inputs[1])
    links.new(transparent.outputs[0], mix.inputs[2])
    opaque = quad_object("Opaque", half_view / 2, 0.0, node_material("Grey", "ShaderNodeBsdfDiffuse"))
    opaque.location.x = -half_view / 2
    partial = quad_object("Partial", half_view / 2, 0.0, mat)
    partial.location.x = half_view / 2
    world_color((1.0, 1.0, 1.0))

    img = render_to_array(sc, samples=64, film_transparent=True)  # row 0 = top
    world = np.zeros((RES, RES), bool)
    world[:7] = world[-7:] = True
    np.testing.assert_array_equal(img[world], 0.0)  # no world in the colour, alpha 0
    left, right = img[10:22, 2:14], img[10:22, 18:30]
    np.testing.assert_array_equal(left[..., 3], 1.0)
    assert left[..., :3].mean() > 0.1  # lit by the world all the same
    assert right[..., 3].mean() == pytest.approx(0.7, abs=0.03)  # 1 - transparent weight

    plain = render_to_array(sc, samples=4, film_transparent=False)
    np.testing.assert_array_equal(plain[..., 3], 1.0)
    brighter = render_to_array(sc, samples=4, film_transparent=False, film_exposure=2.0)
    np.testing.assert_allclose(brighter[..., :3], 2.0 * plain[..., :3], rtol=1e-6)


def oidn_libraries():
    """Open Image Denoise as the bpy wheel ships it (bpy/lib/), which the Denoise node needs."""
    for parent in Path(bpy.__file__).parents:
        found = sorted((parent / "lib").glob("libOpenImageDenoise*.so*"))
        if found or parent.name == "site-packages":
            return found
    return []


OIDN = oidn_libraries()


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
@pytest.mark.skipif(not OIDN, reason="this bpy build has no Open Image Denoise library: the Denoise node cannot run")
def test_denoise_node_reduces_the_error():
    sc = empty_scene_with_camera(48)
    sc.view_layers[0].pathlight.use_pass_denoising_data = True
    quad_object("Wall", 4.0, 0.0, node_material("Wall", "ShaderNodeBsdfDiffuse", Color=(*COLOR, 1)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0.0, -1.0, 0.0))
    bpy.context.object.data.materials.append(node_material("Ball", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.3, 0.2, 1)))
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'AREA'))
    light.data.energy, light.data.size = 400.0, 1.0
    # A disk: area-sampled, so the 1-spp image is about as noisy as the bounds below were set for
    # (a square light is now sampled by solid angle: the ball's 1-spp RMSE fell from 0.112 to
    # 0.067, the denoised one only from 0.042 to 0.036; with the disk 0.094 and 0.040).
    light.data.shape = 'DISK'
    light.location, light.rotation_euler = (2.0, -4.0, 3.0), (math.radians(60), 0.0, math.radians(30))  # towards the wall
    sc.collection.objects.link(light)
    world_color((0.05, 0.05, 0.05))

    reference = render_to_array(sc, samples=256, seed=1)
    noisy = render_to_array(sc, samples=1, seed=2)
    sc.use_nodes = True
    tree = sc.node_tree
    tree.nodes.clear()
    rl, den, out = (tree.nodes.new(t) for t in ("CompositorNodeRLayers", "CompositorNodeDenoise",
                                                "CompositorNodeComposite"))
    den.prefilter = 'ACCURATE'
    den.use_hdr = True
    tree.links.new(rl.outputs["Image"], den.inputs["Image"])
    tree.links.new(rl.outputs["Denoising Normal"], den.inputs["Normal"])
    tree.links.new(rl.outputs["Denoising Albedo"], den.inputs["Albedo"])
    tree.links.new(den.outputs["Image"], out.inputs["Image"])
    noisy_again = render_to_array(sc, samples=1, seed=2)  # compositing off: the same noisy image
    np.testing.assert_array_equal(noisy_again, noisy)
    sc.render.use_compositing = True  # and sc.pathlight.samples is still 1 from above
    with tempfile.TemporaryDirectory() as tmp:  # render_to_array turns compositing off: write here
        path = Path(tmp) / "denoised.exr"
        sc.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        denoised = read_exr(path)
    rmse = lambda a, r=np.s_[:, :]: float(np.sqrt(np.mean((a[r][..., :3] - reference[r][..., :3]) ** 2)))  # noqa: E731
    # Silhouettes keep some of their anti-aliasing noise (the features are noisy there too),
    # so the whole image improves less than the inside of the ball.
    assert rmse(denoised) < 0.7 * rmse(noisy), (rmse(denoised), rmse(noisy))
    ball = np.s_[18:26, 20:28]
    assert rmse(denoised, ball) < 0.5 * rmse(noisy, ball), (rmse(denoised, ball), rmse(noisy, ball))
    assert not np.array_equal(denoised[..., :3], noisy[..., :3])


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_bvh_view_passes_heat_map_and_core_counts(tmp_path, caplog):
    sc = empty_scene_with_camera(RES)
    sc.camera.data.lens = 35.0
    grey = node_material("Grey", "ShaderNodeBsdfDiffuse")
    for i in range(3):  # a cluster of dense spheres on the left, one quad on the right
        for j in range(3):
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(-2.2 + 0.7 * i, 0.3 * j, -1.0 + 0.7 * j))
            bpy.context.object.data.materials.append(grey)
    wall = quad_object("Wall", 0.8, 0.0, grey)
    wall.location = (1.5, 0.0, -0.5)
    sc.view_layers[0].pathlight.use_pass_sample_count = True
    with caplog.at_level(logging.INFO, logger="addon.session"):
        ch = render_multilayer(sc, tmp_path / "bvh.exr", samples=8, debug_view='BVH')
    nodes, tris = ch["BVH Nodes.X"], ch["BVH Triangles.X"]
    np.testing.assert_array_equal(ch["Sample Count.X"], 1.0)  # one ray per pixel centre

    # The same camera rays through the module, on the scene the add-on exports.
    pc = addon.core.get_core()
    warn = Warnings()
    core_scene = to_core(pc, export_scene(bpy.context.evaluated_depsgraph_get(), warn), warn)
    core_scene.commit()
    ys, xs = np.mgrid[RES - 1:-1:-1, 0:RES]  # row 0 of the EXR is the top row
    xy = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1).astype(np.float32)
    o, d, tmax = core_scene.camera_rays(RES, RES, xy)
    n_ref, t_ref = core_scene.traversal_counts(o, d, tmax)
    np.testing.assert_array_equal(nodes.ravel(), n_ref)
    np.testing.assert_array_equal(tris.ravel(), t_ref)
    _, prim, _, _ = core_scene.intersect(o, d, float(tmax.max()))
    hit = (prim >= 0).reshape(RES, RES)
    assert hit.any() and (~hit).any()
    assert np.all(nodes[hit] > 0) and np.all(tris[hit] > 0)
    assert np.all(tris[:4] == 0)  # the top rows look over the whole scene
    cols = np.arange(RES)[None, :].repeat(RES, 0)
    cluster, lone = hit & (cols < RES // 2), hit & (cols > RES * 3 // 4)
    assert nodes[cluster].mean() > nodes[lone].mean()

    # Combined: the heat map, scaled to the image's maximum, which the log states.
    rgb = np.stack([ch["Combined." + c] for c in "RGB"], -1)
    np.testing.assert_allclose(rgb, session.heat_map(nodes, nodes.max())[..., :3], atol=1e-6)
    np.testing.assert_array_equal(rgb[nodes == nodes.max()], np.broadcast_to([1, 0, 0], rgb[nodes == nodes.max()].shape))
    np.testing.assert_array_equal(rgb[nodes == 0], 0.0)
    assert any(f"= {nodes.max():.0f}" in r.getMessage() for r in caplog.records)


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_each_view_layer_gets_its_own_passes(tmp_path):
    sc = wall_scene()
    sc.view_layers[0].use_pass_z = True
    second = sc.view_layers.new("Second")
    second.use_pass_normal = True
    second.pathlight.use_pass_sample_count = True
    render_multilayer(sc, tmp_path / "layers.exr", samples=2)
    with OpenEXR.File(str(tmp_path / "layers.exr"), separate_channels=True) as exr:
        channels = {k: np.array(v.pixels) for k, v in exr.channels().items()}
    layers = {}
    for key in channels:
        layer, name, _ = key.split(".")
        layers.setdefault(layer, set()).add(name)
    assert layers == {"ViewLayer": {"Combined", "Depth"}, "Second": {"Combined", "Normal", "Sample Count"}}
    np.testing.assert_array_equal(channels["Second.Sample Count.X"], 2.0)
    np.testing.assert_array_equal(channels["Second.Combined.R"], channels["ViewLayer.Combined.R"])


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_sample_count_pass_with_adaptive_sampling(tmp_path):
    sc = wall_scene()
    sc.view_layers[0].pathlight.use_pass_sample_count = True
    ch = render_multilayer(sc, tmp_path / "adaptive.exr", samples=128, use_adaptive_sampling=True,
                           adaptive_threshold=0.002, adaptive_min_samples=16)
    counts = ch["Sample Count.X"]
    assert counts.min() >= 16 and counts.max() <= 128
    assert np.all(counts == np.round(counts))  # whole samples, not a fraction
    # The flat world converges at once; the noisy wall takes more samples.
    assert counts[:4].max() < counts[10:22, 10:22].mean()
