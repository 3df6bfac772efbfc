"""Image Texture nodes on UDIM tiles, image sequences and movies (addon/export/image_sources.py):
small tile and frame images written into a temporary folder, each tile or frame its own colour,
rendered by Pathlight and compared with Cycles (stored references, tests/cycles_refs/): an
emissive plane whose UVs cross the tiles seen straight down by an orthographic camera, so that
every pixel is a texture lookup. The frame and path arithmetic is checked against Blender's own
(the evaluated node's ImageUser, Image.filepath_from_user)."""
import numpy as np
import pytest

import bpy

import material_scenes as ms
from blender_util import BOX_FILTER, Warnings, load_addon, render_to_array

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.export.image_sources import image_frame, sequence_path, tile_path  # noqa: E402

MAGENTA = (1.0, 0.0, 1.0)
TILE_COLOURS = {1001: (0.9, 0.2, 0.1), 1002: (0.1, 0.8, 0.2), 1011: (0.2, 0.3, 0.9)}
FRAME_COLOURS = {1: (0.9, 0.5, 0.1), 2: (0.1, 0.6, 0.9), 3: (0.6, 0.1, 0.8)}
PX = 16  # pixels per UV unit


def texels(colour, n=4):
    """n x n RGBA texels of `colour`, every other one half as bright (so Linear filtering and
    the tile borders show), in the image's (sRGB) encoding."""
    px = np.ones((n, n, 4), np.float32)
    px[..., :3] = colour
    px[(np.indices((n, n)).sum(0) % 2) == 1, :3] *= 0.5
    return px


def write_png(path, px, float_exr=False):
    img = bpy.data.images.new("pathlight test writer", px.shape[1], px.shape[0], alpha=True,
                              float_buffer=float_exr)
    try:
        img.pixels.foreach_set(np.ascontiguousarray(px, np.float32).ravel())
        img.filepath_raw = str(path)
        img.file_format = 'OPEN_EXR' if float_exr else 'PNG'
        img.save()
    finally:
        bpy.data.images.remove(img)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("image_sources")
    for number, colour in TILE_COLOURS.items():
        write_png(d / f"tiles.{number}.png", texels(colour))
        write_png(d / f"packed.{number}.png", texels(colour))
        write_png(d / f"hdr.{number}.exr", texels(np.array(colour) * 3.0), float_exr=True)
        px = texels(colour)
        px[::2, :, 3] = 0.25  # every other row mostly transparent
        write_png(d / f"alpha.{number}.png", px)
    for frame, colour in FRAME_COLOURS.items():
        write_png(d / f"seq.{frame:04d}.png", texels(colour))
    return d


def uv_plane_scene(image_fn, uv_min, uv_max, interpolation='Linear', extension='REPEAT', frame=1,
                   alpha=False):
    """build() of an emissive plane whose UVs run from uv_min to uv_max (a grid of quads with
    corners inside every tile, which Cycles' tile culling reads), image_fn() its Image Texture,
    seen by an orthographic camera, PX pixels per UV unit; alpha: mixed with a Transparent BSDF
    by the texture's Alpha (which makes Color the unassociated colour)."""
    (u0, v0), (u1, v1) = uv_min, uv_max

    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        w, h = u1 - u0, v1 - v0
        scene.render.resolution_x, scene.render.resolution_y = round(w * PX), round(h * PX)
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Tiles")
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image_fn()
        tex.interpolation = interpolation
        tex.extension = extension
        if tex.image.source == 'SEQUENCE':
            tex.image_user.frame_duration = len(FRAME_COLOURS)
            tex.image_user.frame_start = 1
        emit = nodes.new("ShaderNodeEmission")
        links.new(tex.outputs["Color"], emit.inputs["Color"])
        if alpha:
            mix = nodes.new("ShaderNodeMixShader")
            links.new(tex.outputs["Alpha"], mix.inputs["Fac"])
            links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[1])
            links.new(emit.outputs[0], mix.inputs[2])
            links.new(mix.outputs[0], out.inputs["Surface"])
        else:
            links.new(emit.outputs[0], out.inputs["Surface"])
        nx, ny = round(w * 4), round(h * 4)
        verts = [(i * w / nx, j * h / ny, 0.0) for j in range(ny + 1) for i in range(nx + 1)]
        faces = [(j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i)
                 for j in range(ny) for i in range(nx)]
        mesh = bpy.data.meshes.new("Plane")
        mesh.from_pydata(verts, [], faces)
        corner_verts = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
        uv = np.array(verts, np.float32)[corner_verts, :2] + np.float32((u0, v0))
        mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", uv.ravel())
        mesh.materials.append(mat)
        obj = bpy.data.objects.new("Plane", mesh)
        obj.location = (-w / 2, -h / 2, 0.0)
        scene.collection.objects.link(obj)
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        cam.data.type = 'ORTHO'
        cam.data.ortho_scale = max(w, h)
        cam.location = (0.0, 0.0, 2.0)
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.frame_set(frame)
        return scene
    return build


def render_both(build, samples=16):
    ours = render_to_array(build(), "PATHLIGHT", samples=samples, max_bounces=0)
    cycles = render_to_array(build(), "CYCLES", samples=samples, max_bounces=0, **BOX_FILTER)
    return ours[..., :3], cycles[..., :3]


def at(img, uv_min, u, v):
    """The pixel of `img` (row 0 = top) at UV (u, v) of a uv_plane_scene."""
    rows = img.shape[0]
    return img[rows - 1 - int((v - uv_min[1]) * PX), int((u - uv_min[0]) * PX)]


def assert_same(ours, cycles, what):
    diff = np.abs(ours - cycles)
    print(f"\n{what}: mean |diff| {diff.mean():.5f}, means {ours.mean():.4f} / {cycles.mean():.4f}")
    assert np.isfinite(ours).all()
    assert diff.mean() < 0.004, what
    assert abs(ours.mean() / cycles.mean() - 1.0) < 0.005, what
    assert np.quantile(diff.max(-1), 0.98) < 0.05, what  # texel edges: sample positions differ


def udim_image(folder, missing=(1003,)):
    img = bpy.data.images.load(str(folder / "tiles.1001.png"))
    img.source = 'TILED'  # finds tiles 1002 and 1011 beside it: tiles.<UDIM>.png
    for number in missing:  # listed, with no file
        img.tiles.new(number)
    return img


UDIM_RANGE = ((-0.5, -0.5), (2.5, 1.5))  # tiles 1001 (and (-1, 0): truncated), 1002, 1003, 1011..1013


@pytest.mark.parametrize("interp, ext", [('Linear', 'REPEAT'), ('Closest', 'EXTEND'), ('Linear', 'CLIP')])
def test_udim_tiles_from_files_match_cycles(folder, interp, ext):
    build = uv_plane_scene(lambda: udim_image(folder), *UDIM_RANGE, interp, ext)
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"UDIM {interp} {ext}")
    lo = UDIM_RANGE[0]
    # The tile of each UV's integer part, magenta where none is (1012, 1013) or it has no
    # file (1003); (-0.25, 0.6) is tile 1001's (truncation), not a missing tile's.
    for (u, v), colour in [((1.6, 0.6), 1002), ((0.6, 1.2), 1011), ((-0.4, 0.6), 1001)]:
        tile = at(ours, lo, u, v)
        assert np.argmax(tile) == np.argmax(TILE_COLOURS[colour]), (u, v, tile)
    # (Tile 1003 is Cycles' stand-in, one magenta texel: Clip fades it out to its borders.)
    for u, v in [(2.2, 0.5)] * (ext != 'CLIP') + [(1.5, 1.2), (2.2, 1.2)]:
        assert np.allclose(at(ours, lo, u, v), MAGENTA, atol=1e-3), (u, v)


def test_packed_and_generated_tiles_match_cycles(folder):
    def packed():
        img = udim_image(folder, missing=())
        img.pack()
        return img

    def generated():
        img = bpy.data.images.new("Generated tiles", 8, 8, tiled=True)
        img.generated_color = (*TILE_COLOURS[1001], 1.0)
        with bpy.context.temp_override(edit_image=img):
            bpy.ops.image.tile_add(number=1002, fill=True, color=(*TILE_COLOURS[1002], 1.0),
                                   generated_type='BLANK', width=4, height=4)
            bpy.ops.image.tile_add(number=1011, fill=True, generated_type='COLOR_GRID',
                                   width=16, height=16)
        return img

    for what, image_fn in (("packed", packed), ("generated", generated)):
        ours, cycles = render_both(uv_plane_scene(image_fn, (0.0, 0.0), (2.0, 2.0)))
        assert_same(ours, cycles, what)
        assert np.argmax(at(ours, (0.0, 0.0), 1.5, 0.5)) == 1  # tile 1002: green


def test_float_tiles_match_cycles(folder):
    """EXR tiles (scene linear, values above 1)."""
    def image():
        img = bpy.data.images.load(str(folder / "hdr.1001.exr"))
        img.source = 'TILED'
        return img
    ours, cycles = render_both(uv_plane_scene(image, (0.0, 0.0), (2.0, 2.0)))
    assert_same(ours, cycles, "EXR tiles")
    assert ours.max() > 1.2 and np.argmax(at(ours, (0.0, 0.0), 1.5, 0.5)) == 1


def test_tiles_alpha_matches_cycles(folder):
    """The Alpha output of a tile set (its own tile set of alpha images) and Color divided by
    the filtered alpha, as Cycles, with a missing tile's stand-in among them."""
    def image():
        img = bpy.data.images.load(str(folder / "alpha.1001.png"))
        img.source = 'TILED'
        img.tiles.new(1012)
        return img
    ours, cycles = render_both(uv_plane_scene(image, (0.0, 0.0), (2.0, 2.0), alpha=True))
    assert_same(ours, cycles, "tiles with alpha")
    opaque = render_to_array(uv_plane_scene(image, (0.0, 0.0), (2.0, 2.0))(), "PATHLIGHT", samples=4,
                             max_bounces=0)[..., :3]
    assert np.abs(ours - opaque).mean() > 0.01  # (Color alone: the associated colour)


def test_unreadable_tiles_warn_once(folder):
    uv_plane_scene(lambda: udim_image(folder, missing=(1003, 1004)), *UDIM_RANGE)()
    images = set(bpy.data.images)
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert set(bpy.data.images) == images  # the temporary tile images are gone
    tile_warnings = [w for w in warnings if "UDIM" in w]
    assert len(tile_warnings) == 1 and "1003" in tile_warnings[0] and "1004" in tile_warnings[0], warnings
    sets = [i for i in data.images if i.tiles]
    assert len(sets) == 1 and sorted(n for n, _ in sets[0].tiles) == [1001, 1002, 1003, 1004, 1011]
    for n, k in sets[0].tiles:  # Cycles' stand-in for the unreadable ones: one magenta texel
        assert (data.images[k].pixels.tolist() == [[[1.0, 0.0, 1.0, 1.0]]]) == (n in (1003, 1004))


def sequence_image(folder):
    img = bpy.data.images.load(str(folder / "seq.0001.png"))
    img.source = 'SEQUENCE'
    return img


@pytest.mark.parametrize("frame", [1, 2])
def test_sequence_frames_match_cycles(folder, frame):
    build = uv_plane_scene(lambda: sequence_image(folder), (0.0, 0.0), (1.0, 1.0), frame=frame)
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"sequence frame {frame}")
    assert nearest_frame(ours) == frame


def nearest_frame(img):
    """The frame of FRAME_COLOURS whose texels' mean (decoded) is nearest to img's mean."""
    mean = img.reshape(-1, 3).mean(0)
    expect = {f: 0.5 * ms.srgb_linear(c) + 0.5 * ms.srgb_linear(np.array(c) * 0.5)
              for f, c in FRAME_COLOURS.items()}
    return min(expect, key=lambda f: np.abs(expect[f] - mean).sum())


def test_sequence_follows_the_frame_in_an_animation(folder):
    """Two frames of one animation (the kept scene of render_cache: persistent data) show the
    two frames' images."""
    build = uv_plane_scene(lambda: sequence_image(folder), (0.0, 0.0), (1.0, 1.0), frame=1)
    scene = build()
    scene.render.use_persistent_data = True
    first = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    scene.frame_set(3)
    third = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    assert (nearest_frame(first), nearest_frame(third)) == (1, 3)


def test_missing_frame_warns_and_is_magenta(folder):
    def image():
        return sequence_image(folder)
    build = uv_plane_scene(image, (0.0, 0.0), (1.0, 1.0), frame=1)
    scene = build()
    tex = bpy.data.materials["Tiles"].node_tree.nodes["Image Texture"]
    tex.image_user.frame_offset = 7  # frame 8: no file
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert any("seq.0008.png" in w and "not found" in w for w in warnings), warnings
    ours = render_to_array(scene, "PATHLIGHT", samples=1, max_bounces=0)
    assert np.allclose(ours[..., :3], MAGENTA, atol=1e-3)
    tex.image_user.frame_offset = 1  # frame 2: read through a temporary image, removed again
    images = set(bpy.data.images)
    export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert set(bpy.data.images) == images


@pytest.mark.parametrize("duration, start, offset, cyclic", [
    (3, 1, 0, False), (3, 2, 4, True), (5, -3, -2, True), (4, 10, 0, False), (1, 1, 0, True), (0, 1, 5, False)])
def test_frame_and_path_are_blenders(folder, duration, start, offset, cyclic):
    """image_frame and sequence_path against Blender's own: the evaluated node's ImageUser
    (Auto Refresh computes its frame) and Image.filepath_from_user."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    img = sequence_image(folder)
    mat, nodes, links, out = ms.new_material("Seq")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = img
    user = tex.image_user
    user.frame_duration, user.frame_start, user.frame_offset = duration, start, offset
    user.use_cyclic, user.use_auto_refresh = cyclic, True
    mesh = bpy.data.meshes.new("M")
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("O", mesh))
    for f in (-7, -1, 0, 1, 2, 3, 4, 5, 11, 250):
        scene.frame_set(f)
        evaluated = mat.evaluated_get(bpy.context.evaluated_depsgraph_get()).node_tree.nodes[tex.name]
        frame = image_frame(user, f)
        assert frame == evaluated.image_user.frame_current, f
        path = sequence_path(bpy.path.abspath(img.filepath), frame)
        assert path == img.filepath_from_user(image_user=evaluated.image_user), f


def test_path_tokens():
    assert tile_path("/a/t.<UDIM>.png", 1012) == "/a/t.1012.png"
    assert tile_path("/a/t_<UVTILE>.exr", 1012) == "/a/t_u2_v2.exr"
    assert sequence_path("/a/b2/render_0007_x.png", 12) == "/a/b2/render_0012_x.png"
    assert sequence_path("/a/f7.exr", 123) == "/a/f123.exr"
    assert sequence_path("/a/nodigits.png", 3) == "/a/nodigits3.png"


def test_movie_renders_its_first_frame_with_a_warning(tmp_path):
    """bpy gives a movie's pixels only as the frame it loaded last: Pathlight renders the first
    frame, and says so at other frames."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.engine = 'BLENDER_WORKBENCH'
    scene.display.shading.background_type = 'WORLD'
    world = bpy.data.worlds.new("W")
    scene.world = world
    for f, c in FRAME_COLOURS.items():
        world.color = c
        world.keyframe_insert("color", frame=f)
    cam = bpy.data.objects.new("C", bpy.data.cameras.new("C"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.image_settings.file_format = 'FFMPEG'
    scene.render.ffmpeg.format = 'AVI'
    scene.render.ffmpeg.codec = 'PNG'
    scene.render.filepath = str(tmp_path / "movie.avi")
    scene.render.use_file_extension = False
    scene.frame_start, scene.frame_end = 1, 3
    bpy.ops.render.render(animation=True)

    def movie():
        img = bpy.data.images.load(str(tmp_path / "movie.avi"), check_existing=False)
        img.colorspace_settings.name = "Non-Color"
        return img
    first = movie()
    expect = np.empty(len(first.pixels), np.float32)
    first.pixels.foreach_get(expect)
    expect = expect.reshape(64, 64, 4)[..., :3].mean((0, 1))
    assert first.source == 'MOVIE' and expect.std() > 0.05
    for frame, warned in ((1, False), (3, True)):
        build = uv_plane_scene(movie, (0.0, 0.0), (1.0, 1.0), frame=frame)
        build()
        warnings = Warnings()
        export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
        assert any("first frame" in w for w in warnings) == warned, warnings
        ours = render_to_array(bpy.context.scene, "PATHLIGHT", samples=4, max_bounces=0)
        assert np.allclose(ours[..., :3].mean((0, 1)), expect, atol=0.01), frame
