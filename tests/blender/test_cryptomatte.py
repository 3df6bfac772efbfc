"""Cryptomatte Object / Material / Asset passes through headless Blender: Cycles' pass names
and layout, the ids and manifests against Cycles' own, coverages against Cycles' within its
seed-to-seed noise, and a matte picked by Blender's compositor Cryptomatte node."""
import json
import math

import bpy
import numpy as np
import OpenEXR
import pytest

from blender_util import core_has, empty_scene_with_camera, load_addon, node_material, render_multilayer_file
from light_scenes import world_color

addon = load_addon()
from addon import session  # noqa: E402

pytestmark = pytest.mark.skipif(not core_has("Session", "film_pass") or
                                not hasattr(addon.core.get_core(), "cryptomatte_hash"),
                                reason="core without Cryptomatte")

RES, SPP = 48, 64
LAYERS = ("CryptoObject", "CryptoMaterial", "CryptoAsset")


def mesh_object(name, verts, faces, material, parent=None):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.parent = parent
    return obj


def square(half, y, x=0.0, z=0.0):
    return [(x - half, y, z - half), (x + half, y, z - half), (x + half, y, z + half), (x - half, y, z + half)]


def crypto_scene():
    """Camera at (0, -6, 0) looking along +y: a back wall "Back"; a square "Box" and a ball
    "Ball" of one shared material "Shared", the ball parented (through "Arm") to the empty
    "Rig"; a sheet "Veil" (Diffuse mixed half and half with a Transparent BSDF) over the left
    of the ball and the wall. Cryptomatte Object, Material and Asset on, 4 levels."""
    sc = empty_scene_with_camera(RES)
    world_color((0.2, 0.2, 0.2))
    shared = node_material("Shared", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.4, 0.2, 1))
    mesh_object("Back", square(3.0, 1.0), [(0, 1, 2, 3)],
                node_material("Wall", "ShaderNodeBsdfDiffuse", Color=(0.5, 0.5, 0.5, 1)))
    mesh_object("Box", square(0.5, -0.5, x=1.0, z=-0.6), [(0, 1, 2, 3)], shared)
    rig = bpy.data.objects.new("Rig", None)
    arm = bpy.data.objects.new("Arm", None)
    sc.collection.objects.link(rig)
    sc.collection.objects.link(arm)
    arm.parent = rig
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7, location=(-0.4, 0.0, 0.4), segments=24, ring_count=12)
    ball = bpy.context.object
    ball.name = "Ball"
    ball.data.materials.append(shared)
    ball.parent = arm
    veil = bpy.data.materials.new("Veil")
    veil.use_nodes = True
    nodes, links = veil.node_tree.nodes, veil.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    mix, tra, dif = nodes.new("ShaderNodeMixShader"), nodes.new("ShaderNodeBsdfTransparent"), nodes.new("ShaderNodeBsdfDiffuse")
    mix.inputs["Fac"].default_value = 0.5
    links.new(dif.outputs[0], mix.inputs[1])
    links.new(tra.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], nodes["Material Output"].inputs["Surface"])
    mesh_object("Veil", [(-2.0, -1.5, -1.0), (-0.4, -1.5, -1.0), (-0.4, -1.5, 1.5), (-2.0, -1.5, 1.5)],
                [(0, 1, 2, 3)], veil)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.rotation_euler = (math.radians(40), 0.0, math.radians(20))
    sc.collection.objects.link(sun)
    vl = sc.view_layers[0]
    vl.use_pass_cryptomatte_object = vl.use_pass_cryptomatte_material = vl.use_pass_cryptomatte_asset = True
    vl.pass_cryptomatte_depth = 4
    return sc


def render(sc, engine, path, seed=0, samples=SPP):
    """Multilayer EXR render with `engine` (Blackman-Harris 1.5 px, both engines' default):
    (channels, header)."""
    sc.render.engine = engine
    if engine == 'CYCLES':
        sc.cycles.device, sc.cycles.samples, sc.cycles.seed = 'CPU', samples, seed
        sc.cycles.use_denoising = sc.cycles.use_adaptive_sampling = False
        sc.cycles.pixel_filter_type, sc.cycles.filter_width = 'BLACKMAN_HARRIS', 1.5
    else:
        sc.pathlight.samples, sc.pathlight.seed = samples, seed
        sc.pathlight.use_adaptive_sampling = False
        sc.pathlight.filter_type, sc.pathlight.filter_width = 'BLACKMAN_HARRIS', 1.5
    channels = render_multilayer_file(sc, path)
    with OpenEXR.File(str(path)) as exr:
        header = {k: v for k, v in exr.header().items() if k.startswith("cryptomatte/")}
    return channels, header


def coverage(channels, layer, id_):
    """The coverage of id_ in a Cryptomatte layer: its weight summed over the ranked slots."""
    out = 0.0
    for p in range(2):
        for i, w in (("r", "g"), ("b", "a")):
            out = out + np.where(channels[f"{layer}{p:02d}.{i}"] == id_, channels[f"{layer}{p:02d}.{w}"], 0.0)
    return out


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("crypto")
    sc = crypto_scene()
    out = {"pathlight": render(sc, 'PATHLIGHT', tmp / "pl.exr"),
           "cycles": render(sc, 'CYCLES', tmp / "cy0.exr", seed=0),
           "cycles_seed": render(sc, 'CYCLES', tmp / "cy1.exr", seed=1)}
    return sc, out


def ids_of(pc, *names):
    return [np.float32(pc.cryptomatte_id(pc.cryptomatte_hash(n))) for n in names]


def test_passes_and_sockets_as_cycles(renders):
    sc, out = renders
    pl, cy = out["pathlight"][0], out["cycles"][0]
    crypto = lambda ch: {k for k in ch if k.startswith("Crypto")}  # noqa: E731
    # Two RGBA passes per layer for 4 levels: CryptoObject00.r ... CryptoAsset01.a, as Cycles.
    assert crypto(pl) == crypto(cy) == {f"{l}{p:02d}.{c}" for l in LAYERS for p in range(2) for c in "rgba"}
    sc.render.engine = 'PATHLIGHT'
    sc.use_nodes = True
    rl = sc.node_tree.nodes.new("CompositorNodeRLayers")
    assert {f"{l}{p:02d}" for l in LAYERS for p in range(2)} <= {s.name for s in rl.outputs if s.enabled}


def test_ids_and_manifests_match_cycles(renders):
    pc = addon.core.get_core()
    _, out = renders
    (pl, pl_head), (cy, cy_head) = out["pathlight"], out["cycles"]
    for layer in LAYERS:
        for p in range(2):
            for c in "rb":
                a, b = pl[f"{layer}{p:02d}.{c}"], cy[f"{layer}{p:02d}.{c}"]
                assert set(np.unique(a)) == set(np.unique(b)), (layer, p, c)
    # The top-ranked id agrees wherever one surface clearly dominates in both renders.
    for layer in LAYERS:
        sure = (pl[f"{layer}00.g"] > 0.9) & (cy[f"{layer}00.g"] > 0.9)
        assert sure.sum() > RES * RES // 3
        np.testing.assert_array_equal(pl[f"{layer}00.r"][sure], cy[f"{layer}00.r"][sure])
    back, box, ball, veil = ids_of(pc, "Back", "Box", "Ball", "Veil")
    assert {back, box, ball, veil} <= set(np.unique(pl["CryptoObject00.r"]))
    rig, shared = ids_of(pc, "Rig", "Shared")
    assert rig in set(np.unique(pl["CryptoAsset00.r"])) and shared in set(np.unique(pl["CryptoMaterial00.r"]))
    # Metadata: the same keys as Cycles', name / hash / conversion equal, every manifest entry
    # of Pathlight's with Cycles' hash.
    assert set(pl_head) == set(cy_head) and len(pl_head) == 4 * len(LAYERS)
    for key, value in pl_head.items():
        if key.endswith("/manifest"):
            ours, theirs = json.loads(value), json.loads(cy_head[key])
            assert ours and all(theirs.get(n) == h for n, h in ours.items()), (ours, theirs)
        else:
            assert value == cy_head[key]
    names = {v for k, v in pl_head.items() if k.endswith("/name")}
    assert names == {f"ViewLayer.{l}" for l in LAYERS}
    manifest = json.loads(next(v for k, v in pl_head.items() if k.endswith("/manifest") and
                               pl_head[k[:-len("manifest")] + "name"] == "ViewLayer.CryptoObject"))
    assert manifest["Ball"] == f"{pc.cryptomatte_hash('Ball'):08x}"


def regions(img, size=8):
    return img.reshape(RES // size, size, RES // size, size).mean(axis=(1, 3))


def test_coverages_match_cycles_within_its_noise(renders):
    pc = addon.core.get_core()
    _, out = renders
    pl, cy, cy2 = out["pathlight"][0], out["cycles"][0], out["cycles_seed"][0]
    checks = [("CryptoObject", n) for n in ("Back", "Box", "Ball", "Veil")] + \
             [("CryptoMaterial", n) for n in ("Shared", "Wall", "Veil")] + [("CryptoAsset", n) for n in ("Rig", "Box")]
    for layer, name in checks:
        (id_,) = ids_of(pc, name)
        a, b, c = coverage(pl, layer, id_), coverage(cy, layer, id_), coverage(cy2, layer, id_)
        # Means as a share of the image, and the worst 8x8 region, against Cycles' own seed noise.
        mean_diff, seed_mean = abs(a.mean() - b.mean()), abs(c.mean() - b.mean())
        worst, seed_worst = np.abs(regions(a) - regions(b)).max(), np.abs(regions(c) - regions(b)).max()
        print(f"{layer} {name}: mean {a.mean():.4f} vs {b.mean():.4f} (Cycles seeds {abs(c.mean() - b.mean()):.4f}); "
              f"worst 8x8 {worst:.4f} (Cycles seeds {seed_worst:.4f})")
        # Means within 1 % of the coverage (or twice Cycles' seed noise), regions within 0.01
        # of full coverage (or twice Cycles' seed noise there).
        assert mean_diff < max(0.01 * b.mean(), 2.0 * seed_mean), (layer, name, mean_diff, seed_mean)
        assert worst < max(0.01, 2.0 * seed_worst), (layer, name, worst, seed_worst)


def test_farm_merge_ranks_the_ids_again(renders, tmp_path):
    """Two halves of the sample range, merged by build.py merge, give the full render's
    Cryptomatte (ids merged, not averaged) and keep its manifests."""
    import build
    pc = addon.core.get_core()
    sc, out = renders
    halves = []
    for k in range(2):
        sc.pathlight.sample_offset = k * SPP // 2
        path = tmp_path / f"half{k}.exr"
        render(sc, 'PATHLIGHT', path, samples=SPP // 2)
        halves.append(str(path))
    sc.pathlight.sample_offset = 0
    sc.pathlight.samples = SPP
    build.merge_exr(halves, str(tmp_path / "merged.exr"))
    with OpenEXR.File(str(tmp_path / "merged.exr"), separate_channels=True) as exr:
        header = {k: v for k, v in exr.header().items() if k.startswith("cryptomatte/")}
        merged = {k.split(".", 1)[1]: np.array(v.pixels, np.float32) for k, v in exr.channels().items()}
    full, full_header = out["pathlight"]
    assert header == full_header
    for layer, name in (("CryptoObject", "Back"), ("CryptoObject", "Veil"), ("CryptoObject", "Ball"),
                        ("CryptoMaterial", "Shared"), ("CryptoAsset", "Rig")):
        (id_,) = ids_of(pc, name)
        np.testing.assert_allclose(coverage(merged, layer, id_), coverage(full, layer, id_), atol=1e-5)
    w = np.stack([merged[f"CryptoObject{p:02d}.{c}"] for p in range(2) for c in "ga"])
    assert np.all(np.diff(w, axis=0) <= 0)  # ranked again


def test_compositor_cryptomatte_node_picks_an_object(renders, tmp_path):
    """Blender's own Cryptomatte node (CompositorNodeCryptomatteV2, source Render) extracts the
    ball's matte from a Pathlight render: the ball's coverage from the passes."""
    pc = addon.core.get_core()
    sc, out = renders
    sc.render.engine = 'PATHLIGHT'
    sc.pathlight.samples, sc.pathlight.seed = SPP, 0
    sc.use_nodes = True
    tree = sc.node_tree
    tree.nodes.clear()
    rl, crypto, comp = (tree.nodes.new(t) for t in ("CompositorNodeRLayers", "CompositorNodeCryptomatteV2",
                                                     "CompositorNodeComposite"))
    crypto.source = 'RENDER'
    crypto.scene = sc
    crypto.layer_name = "ViewLayer.CryptoObject"
    crypto.matte_id = "Ball"
    tree.links.new(rl.outputs["Image"], crypto.inputs["Image"])
    tree.links.new(crypto.outputs["Matte"], comp.inputs["Image"])
    sc.render.use_compositing = True
    image = sc.render.image_settings
    image.file_format, image.color_mode, image.color_depth = 'OPEN_EXR', 'RGBA', '32'
    sc.render.filepath = str(tmp_path / "matte.exr")
    sc.render.use_file_extension = False
    bpy.ops.render.render(write_still=True, scene=sc.name)
    with OpenEXR.File(str(tmp_path / "matte.exr")) as exr:
        channels = exr.channels()
        matte = np.array(channels["RGBA"].pixels if "RGBA" in channels else channels["R"].pixels, np.float32)
    matte = matte[..., 0] if matte.ndim == 3 else matte
    (ball,) = ids_of(pc, "Ball")
    truth = coverage(out["pathlight"][0], "CryptoObject", ball)  # the same render (seed, samples)
    assert truth.max() > 0.9 and truth.sum() > 50
    np.testing.assert_allclose(matte, truth, atol=1e-5)
