"""Image Texture nodes on UDIM tiles, image sequences and movies (addon/export/image_sources.py):
small tile and frame images written into a temporary folder, each tile or frame its own colour,
rendered by Pathlight and compared with Cycles (stored references, tests/cycles_refs/): an
emissive plane whose UVs cross the tiles seen straight down by an orthographic camera, so that
every pixel is a texture lookup. The frame and path arithmetic is checked against Blender's own
(the evaluated node's ImageUser, Image.filepath_from_user)."""
import os

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
                   alpha=False, quads_per_unit=4, mapping=False):
    """build() of an emissive plane whose UVs run from uv_min to uv_max (a grid of quads with
    corners inside every tile, which Cycles' tile culling reads), image_fn() its Image Texture,
    seen by an orthographic camera, PX pixels per UV unit; alpha: mixed with a Transparent BSDF
    by the texture's Alpha (which makes Color the unassociated colour); quads_per_unit: the
    grid's quads per UV unit (0: one quad)."""
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
        if mapping:  # the Vector through a Mapping node: "identity" or with a Z "offset"
            uv = nodes.new("ShaderNodeTexCoord")
            mp = nodes.new("ShaderNodeMapping")
            if mapping == "offset":
                mp.inputs["Location"].default_value = (0.0, 0.0, 0.5)
            links.new(uv.outputs["UV"], mp.inputs["Vector"])
            links.new(mp.outputs["Vector"], tex.inputs["Vector"])
        nx, ny = max(round(w * quads_per_unit), 1), max(round(h * quads_per_unit), 1)
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


@pytest.mark.parametrize("mapping", [None, "identity", "offset"])
def test_tiles_without_a_uv_corner_are_culled_as_in_cycles(folder, mapping):
    """One quad whose UVs run from (0, 0) to (3, 1): its corners lie in tiles 1001 and 1003
    only (u = 3 counts for tile 1003), so Cycles' final render drops tile 1002 of the image
    (cull_tiles) and reads magenta there, also through an identity Mapping node (which its
    constant folding bypasses); through any other Mapping the Vector is not a UV map and
    every tile stays."""
    build = uv_plane_scene(lambda: udim_image(folder, missing=()), (0.0, 0.0), (3.0, 1.0),
                           quads_per_unit=0, mapping=mapping)
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"one quad over tiles 1001-1003, mapping {mapping}")
    middle = at(ours, (0.0, 0.0), 1.5, 0.5)
    if mapping == "offset":
        assert np.argmax(middle) == 1, middle  # tile 1002: green
    else:
        assert np.allclose(middle, MAGENTA, atol=1e-3), middle
    assert np.argmax(at(ours, (0.0, 0.0), 0.5, 0.5)) == 0  # tile 1001: red, kept


def test_tile_culling_is_for_final_renders_only(folder):
    """The viewport's export (cull_udim_tiles False) keeps every tile, as Cycles' viewport;
    the final render's keeps the tiles with a UV corner in them (u = 3, v = 1 count for tile
    1003: within 1e-6 above a tile's left or lower edge is the tile before)."""
    uv_plane_scene(lambda: udim_image(folder, missing=()), (0.0, 0.0), (3.0, 1.0), quads_per_unit=0)()
    for cull, expect in ((False, [1001, 1002, 1011]), (True, [1001])):
        data = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings(), cull_udim_tiles=cull)
        sets = [i for i in data.images if i.pixels is None]
        assert [sorted(n for n, _ in s.tiles) for s in sets] == [expect], cull
    from addon.export import uv_tiles
    assert uv_tiles([(0, 0), (3, 1), (1.0000001, 2.5), (-0.5, 0.5), (9.5, 0), (10.0, 0), (2, -1.5)]) \
        == {1001, 1003, 1021, 1010}


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


MOVIE_FRAMES = 3


@pytest.fixture(scope="module")
def movie_file(folder):
    """A movie of MOVIE_FRAMES frames, frame f the 4 x 4 texels of FRAME_COLOURS[f] as blocks
    of 4 x 4 pixels (16 x 16: FFmpeg's smallest; lossless: PNG frames in an AVI), written by
    Blender's sequencer from PNG frames."""
    for frame, colour in FRAME_COLOURS.items():
        write_png(folder / f"movie_frame.{frame:04d}.png", np.kron(texels(colour), np.ones((4, 4, 1))))
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.sequence_editor_create()
    strip = scene.sequence_editor.strips.new_image("frames", str(folder / "movie_frame.0001.png"), 1, 1)
    for frame in range(2, MOVIE_FRAMES + 1):
        strip.elements.append(f"movie_frame.{frame:04d}.png")
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = 'Standard'
    scene.render.image_settings.file_format = 'FFMPEG'
    scene.render.ffmpeg.format = 'AVI'
    scene.render.ffmpeg.codec = 'PNG'
    scene.render.filepath = str(folder / "movie.avi")
    scene.render.use_file_extension = False
    scene.frame_start, scene.frame_end = 1, MOVIE_FRAMES
    bpy.ops.render.render(animation=True)
    path = folder / "movie.avi"
    # The same bytes at every run (the stored Cycles reference's key hashes them): FFmpeg's AVI
    # writer records the time of writing (INFO ICRD, "YYYY/MM/DD hh:mm:ss").
    data = bytearray(path.read_bytes())
    at = data.find(b"ICRD")
    if at >= 0:
        size = int.from_bytes(data[at + 4:at + 8], "little")
        data[at + 8:at + 8 + size] = b"2000/01/01 00:00:00\0"[:size].ljust(size, b"\0")
        path.write_bytes(bytes(data))
    return path


def movie_image(path, duration=MOVIE_FRAMES, start=1, offset=0, cyclic=False):
    """image_fn of uv_plane_scene: the movie, its node's Image User set as given."""
    def image():
        img = bpy.data.images.load(str(path), check_existing=False)
        assert img.source == 'MOVIE'
        return img

    def user(tex):
        u = tex.image_user
        u.frame_duration, u.frame_start, u.frame_offset, u.use_cyclic = duration, start, offset, cyclic
    image.user = user
    return image


def movie_scene(path, frame, **user):
    image_fn = movie_image(path, **user)
    build = uv_plane_scene(image_fn, (0.0, 0.0), (1.0, 1.0), frame=frame)

    def build_movie():
        scene = build()
        image_fn.user(bpy.data.materials["Tiles"].node_tree.nodes["Image Texture"])
        return scene
    return build_movie


def written_frame(folder, frame):
    """The RGBA of the PNG that became movie frame `frame` (byte/255, row 0 = bottom)."""
    img = bpy.data.images.load(str(folder / f"movie_frame.{frame:04d}.png"), check_existing=False)
    try:
        px = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(img.size[1], img.size[0], 4)
    finally:
        bpy.data.images.remove(img)


@pytest.mark.parametrize("scene_frame, user, frame", [
    (1, {}, 1), (2, {}, 2), (3, {}, 3),
    (5, dict(start=2, offset=1, cyclic=True), 2),  # cyclic: (5 - 2 + 1) mod 3 = 1, + 1
    (5, dict(duration=5), 3),  # frame 5 of a 3-frame file: its last
])
def test_movie_frames_match_cycles(movie_file, scene_frame, user, frame):
    """The frame of the node's Image User at the scene frame, as Cycles renders it (64
    samples: a texel per pixel, Linear, is noisier than the sequences' 4 pixels per texel;
    the same frame as a PNG renders identically in both engines, measured 2026-12-08)."""
    ours, cycles = render_both(movie_scene(movie_file, scene_frame, **user), samples=64)
    assert_same(ours, cycles, f"movie at scene frame {scene_frame} {user}")
    assert nearest_frame(ours) == frame


def test_movie_frame_pixels_are_the_files(movie_file):
    """The decoded frames are the written frames' bytes exactly, also in the world's
    Environment Texture (read_pixels), at any order of reading and from the cache."""
    from addon.export.image import read_pixels
    from addon.export import image_sources
    folder = movie_file.parent
    image_sources.clear_movie_cache()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    env = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(movie_file), check_existing=False)
    env.image.colorspace_settings.name = "Non-Color"
    env.image_user.frame_duration = MOVIE_FRAMES
    images = set(bpy.data.images)
    for frame in (3, 1, 2, 3):
        buf, why = read_pixels(env.image, env.image_user, frame)
        assert why is None and np.array_equal(buf, written_frame(folder, frame)), frame
    assert set(bpy.data.images) == images  # (the temporary images are gone)


def test_movie_frames_are_decoded_once(movie_file, monkeypatch):
    """Each (file, frame) is decoded once in a session; a rewritten file is decoded again."""
    from addon.export import image_sources
    decoded = []
    decode = image_sources.decode_movie_frame
    monkeypatch.setattr(image_sources, "decode_movie_frame",
                        lambda tmp, frame: (decoded.append(frame), decode(tmp, frame)))
    image_sources.clear_movie_cache()
    movie_scene(movie_file, 2)()
    first = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    again = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert decoded == [2]
    assert [i.pixels.tobytes() for i in first.images] == [i.pixels.tobytes() for i in again.images]
    stat = movie_file.stat()
    os.utime(movie_file, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert decoded == [2, 2]


def test_movie_follows_the_frame_in_an_animation(movie_file):
    """Two frames of one animation (persistent data: the kept scene is rebuilt)."""
    scene = movie_scene(movie_file, 1)()
    scene.render.use_persistent_data = True
    first = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    scene.frame_set(3)
    third = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    assert (nearest_frame(first), nearest_frame(third)) == (1, 3)


def test_movie_frame_that_cannot_be_decoded_is_the_first_with_a_warning(movie_file, monkeypatch):
    from addon.export import image_sources

    def fail(tmp, frame):
        raise RuntimeError("no such frame")
    image_sources.clear_movie_cache()
    monkeypatch.setattr(image_sources, "decode_movie_frame", fail)
    first = render_to_array(movie_scene(movie_file, 1)(), "PATHLIGHT", samples=4, max_bounces=0)
    movie_scene(movie_file, 3)()
    images = set(bpy.data.images)
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert set(bpy.data.images) == images
    assert any("frame 3 cannot be decoded" in w and "first frame" in w for w in warnings), warnings
    ours = render_to_array(bpy.context.scene, "PATHLIGHT", samples=4, max_bounces=0)
    assert nearest_frame(ours[..., :3]) == 1 and np.array_equal(ours, first)


def test_world_movie_frame_matches_cycles(movie_file):
    """The world's Environment Texture shows the frame of its Image User at the scene frame,
    as Cycles (a wide lens along the horizon; 4 x 4 pixel regions)."""
    def build(frame):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        world = bpy.data.worlds.new("W")
        world.use_nodes = True
        nt = world.node_tree
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(str(movie_file), check_existing=False)
        # (Non-Color: the world fast path filters sRGB bytes after decoding them, Cycles
        # before, which differs at the checker's hard texel edges: docs/materials.md)
        env.image.colorspace_settings.name = "Non-Color"
        env.image_user.frame_duration = MOVIE_FRAMES
        nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
        scene.world = world
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        cam.data.lens = 12.0
        cam.rotation_euler = (np.pi / 2, 0.0, 0.3)
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.frame_set(frame)
        return scene

    def regions(img):
        return img[..., :3].reshape(8, 4, 8, 4, 3).mean((1, 3))
    ours = {f: render_to_array(build(f), "PATHLIGHT", samples=16, max_bounces=0) for f in (1, 3)}
    cycles = render_to_array(build(3), "CYCLES", samples=16, max_bounces=0, **BOX_FILTER)
    print(f"\nworld movie frame 3: max region |diff| {np.abs(regions(ours[3]) - regions(cycles)).max():.4f}")
    np.testing.assert_allclose(regions(ours[3]), regions(cycles), atol=0.02)
    assert np.abs(regions(ours[3]) - regions(ours[1])).max() > 0.1  # (frame 1 is not frame 3)
