"""Byte images in colour spaces other than sRGB, Non-Color and the linear ones, converted to
scene linear by OpenColorIO with Blender's config (addon/export/ocio.py), against Cycles (which
converts them with the same library at load; stored references, tests/cycles_refs/): a byte PNG
of saturated and grey texels on an emissive plane, one render per space."""
import os
import sys

import numpy as np
import pytest

import bpy

from blender_util import Warnings, load_addon, render_to_array
from test_image_sources_cycles import render_both, uv_plane_scene, write_png

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.export import ocio  # noqa: E402
from addon.export.image import read_pixels, srgb_to_linear  # noqa: E402
from addon.export.ocio import Unsupported, bindings, load_config, to_scene_linear  # noqa: E402

# 4 x 4 texels: saturated primaries and secondaries, greys, and mixes (sRGB-encoded bytes).
TEXELS = np.array([[(0.9, 0.1, 0.1), (0.1, 0.85, 0.15), (0.1, 0.2, 0.95), (0.95, 0.9, 0.1)],
                   [(0.05, 0.05, 0.05), (0.25, 0.25, 0.25), (0.5, 0.5, 0.5), (0.75, 0.75, 0.75)],
                   [(1.0, 1.0, 1.0), (0.6, 0.3, 0.8), (0.2, 0.7, 0.6), (0.8, 0.45, 0.2)],
                   [(0.0, 0.0, 0.0), (0.35, 0.6, 0.3), (0.9, 0.6, 0.7), (0.15, 0.3, 0.5)]], np.float32)

SPACES = ["Display P3", "Rec.1886", "Rec.2020", "ACEScg", "ACES2065-1", "Linear DCI-P3 D65",
          "Linear CIE-XYZ D65", "Filmic Log", "Filmic sRGB", "AgX Base sRGB", "AgX Log", "Khronos PBR Neutral sRGB"]


@pytest.fixture(scope="module")
def png(tmp_path_factory):
    path = tmp_path_factory.mktemp("colour_spaces") / "texels.png"
    px = np.ones((4, 4, 4), np.float32)
    px[..., :3] = TEXELS
    write_png(path, px)
    return path


def image_in(png, space):
    def load():
        img = bpy.data.images.load(str(png))
        img.colorspace_settings.name = space
        return img
    return load


def texel_means(img):
    """(4, 4, 3) means of the 4 x 4 pixel blocks of a 16 x 16 render (row 0 = bottom, as the
    image's rows)."""
    return img.reshape(4, 4, 4, 4, 3).mean(axis=(1, 3))[::-1]


@pytest.mark.parametrize("space", SPACES)
def test_byte_image_in_space_matches_cycles(png, space):
    """The converted texels (what the export hands the core) against Cycles' render of them
    (Closest: 4 x 4 pixels a texel; Cycles stores them as half floats), out-of-gamut negative
    components included; and Pathlight's render of them, where they are in gamut (the core
    renders negative emission as zero, as before)."""
    build = uv_plane_scene(image_in(png, space), (0.0, 0.0), (1.0, 1.0), 'Closest')
    build()
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert not [w for w in warnings if "colour space" in w], warnings
    (image,) = [i for i in data.images if i.name == "texels.png"]
    assert not image.srgb
    ours, cycles = render_both(build)
    t_cycles, t_ours = texel_means(cycles), texel_means(ours)
    scale = np.abs(t_cycles).max(-1, keepdims=True) + 0.01
    exported_err = np.abs(image.pixels[..., :3] - t_cycles) / scale
    in_gamut = (t_cycles >= 0).all(-1)
    render_err = (np.abs(t_ours - t_cycles) / scale)[in_gamut]
    print(f"\n{space}: worst texel error {exported_err.max():.5f} (exported), {render_err.max():.5f} "
          f"(rendered, {in_gamut.sum()} texels in gamut)")
    # Cycles keeps OCIO's result in half floats (11 bits): 0.1 % apart, and more through the
    # AgX chains' 3D LUT and their 2^12-scaled log range.
    tol = 0.008 if space.startswith("AgX") else 0.004
    assert exported_err.max() < tol, (space, image.pixels[..., :3], t_cycles)
    assert render_err.max() < tol and in_gamut.sum() >= 4, space
    srgb = render_to_array(uv_plane_scene(image_in(png, "sRGB"), (0.0, 0.0), (1.0, 1.0), 'Closest')(),
                           "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    assert np.abs(texel_means(srgb) - t_ours).max() > 0.01  # (not the sRGB decoding it had before)


def test_conversions_read_from_the_config():
    """Every colour space of Blender's config, inactive ones included, either converts (white
    stays white through the display spaces; sRGB is the IEC curve the core decodes) or raises
    Unsupported with the library's reason: in Blender 4.5's config only AgX False Color, whose
    view transform has a singular matrix (an inverse OCIO cannot build)."""
    ocio_lib, config = bindings(), load_config()
    names = list(config.getColorSpaceNames(ocio_lib.SEARCH_REFERENCE_SPACE_ALL, ocio_lib.COLORSPACE_ALL))
    assert "Luminance Compensation sRGB" in names and "Khronos PBR Neutral sRGB" in names
    unsupported = {}
    white = np.ones((1, 3), np.float32)
    for name in names:
        if config.getColorSpace(name).isData():
            continue
        try:
            out = to_scene_linear(white, name)
        except Unsupported as e:
            unsupported[name] = str(e)
            continue
        assert np.isfinite(out).all(), name
        if name in ("sRGB", "Display P3", "Rec.1886", "Rec.2020", "Linear Rec.709", "ACEScg"):
            assert np.allclose(out, 1.0, atol=5e-4), (name, out)
    print(unsupported)
    assert set(unsupported) == {"AgX False Color Rec.709", "AgX False Color P3", "AgX False Color Rec.2020"}, \
        unsupported
    assert all("Singular" in why for why in unsupported.values()), unsupported
    # (OCIO's moncurve: the linear segment's slope is 12.923 for continuity, not 12.92; its CPU
    # processors compute powers by a fast approximation, as in Cycles: 2.4e-5 at 1)
    x = np.linspace(0.0, 1.0, 256, dtype=np.float32)[:, None].repeat(3, 1)
    iec = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    assert np.allclose(to_scene_linear(x, "sRGB"), iec, rtol=3e-5, atol=1e-6)
    # Luminance Compensation (inactive in Blender's config: no image can use it) converts too: a
    # scene-linear space whose inverse keeps in-gamut greys as they are
    lum = to_scene_linear(TEXELS, "Luminance Compensation sRGB")
    assert np.isfinite(lum).all() and np.allclose(lum[1], TEXELS[1], atol=1e-3), lum


def test_big_images_convert_in_chunks_as_one():
    """to_scene_linear's chunks (run on threads) give what one call on the whole array gives,
    leave the input as it is, and keep its shape."""
    rng = np.random.default_rng(3)
    x = (rng.integers(0, 256, (700, 1000, 3)) / 255.0).astype(np.float32)  # 2.7 chunks
    before = x.copy()
    out = to_scene_linear(x, "AgX Base sRGB")
    whole = x.reshape(-1, 3).copy()
    ocio.processor("AgX Base sRGB").applyRGB(whole)
    assert out.shape == x.shape and np.array_equal(x, before)
    assert np.array_equal(out.reshape(-1, 3), whole)


def _export_texels(png, space):
    build = uv_plane_scene(image_in(png, space), (0.0, 0.0), (1.0, 1.0), 'Closest')
    build()
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    (image,) = [i for i in data.images if i.name == "texels.png"]
    raw, _ = read_pixels(bpy.data.images["texels.png"])  # (byte / 255, as Blender reads it)
    return image, warnings, raw[..., :3]


def test_a_space_without_a_processor_warns_and_decodes_as_srgb(png, tmp_path, monkeypatch):
    """A space whose processor OCIO cannot build (here: $OCIO, read as Blender reads it, names
    a config whose 'Display P3' needs a LUT file that is not there) is decoded as sRGB, with a
    warning naming the space and the library's reason."""
    (tmp_path / "config.ocio").write_text(
        "ocio_profile_version: 2\nsearch_path: luts\nroles:\n  scene_linear: Linear Rec.709\n"
        "  default: Linear Rec.709\ncolorspaces:\n  - !<ColorSpace>\n    name: Linear Rec.709\n"
        "  - !<ColorSpace>\n    name: Display P3\n"
        "    to_scene_reference: !<FileTransform> {src: missing_p3.spi1d}\n")
    monkeypatch.setenv("OCIO", str(tmp_path / "config.ocio"))
    image, warnings, raw = _export_texels(png, "Display P3")
    assert any("Display P3" in w and "missing_p3.spi1d" in w for w in warnings), warnings
    assert np.array_equal(image.pixels[..., :3], srgb_to_linear(raw))
    monkeypatch.delenv("OCIO")
    image, warnings, _ = _export_texels(png, "Display P3")  # (Blender's own config again)
    assert not [w for w in warnings if "colour space" in w], warnings


def test_missing_bindings_warn_and_decode_as_srgb(png, monkeypatch):
    """Without importable bindings (the import refused, as in a Python without them) byte
    images in other spaces are decoded as sRGB, as before the conversion existed, with a
    warning naming the space and the missing library."""
    import builtins
    real_import = builtins.__import__

    def refuse(name, *args, **kwargs):
        if name.split(".")[0] == "PyOpenColorIO":
            raise ImportError(f"No module named '{name}'")
        return real_import(name, *args, **kwargs)

    ocio.bindings.cache_clear()
    ocio._config.cache_clear()
    ocio._processor.cache_clear()
    monkeypatch.setitem(sys.modules, "PyOpenColorIO", None)  # (a loaded module is not re-found)
    monkeypatch.setattr(builtins, "__import__", refuse)
    try:
        image, warnings, raw = _export_texels(png, "ACEScg")
    finally:
        ocio.bindings.cache_clear()
    assert any("ACEScg" in w and "PyOpenColorIO" in w for w in warnings), warnings
    assert np.array_equal(image.pixels[..., :3], srgb_to_linear(raw))


def test_bindings_found_as_blender_finds_them(monkeypatch):
    """The wheel's PyOpenColorIO (not importable as it is) is found under bpy's version folder,
    with sys.path left as it was; one that Python imports (Blender's own) is taken as it is."""
    import types
    for name in [n for n in sys.modules if n.split(".")[0] == "PyOpenColorIO"]:
        monkeypatch.delitem(sys.modules, name)  # (restored after the test)
    path = list(sys.path)
    ocio.bindings.cache_clear()
    try:
        found = bindings()
        folder = os.path.dirname(os.path.dirname(found.__file__))
        assert found.__file__.startswith(bpy.utils.resource_path('LOCAL'))
        assert sys.path == path and folder not in sys.path
        assert found.Config.CreateFromFile(ocio.config_path()).getColorSpace("ACEScg") is not None
        ocio.bindings.cache_clear()
        own = types.ModuleType("PyOpenColorIO")
        monkeypatch.setitem(sys.modules, "PyOpenColorIO", own)
        monkeypatch.setattr(ocio, "_bindings_dirs", lambda: pytest.fail("looked past the plain import"))
        assert bindings() is own
    finally:
        ocio.bindings.cache_clear()
