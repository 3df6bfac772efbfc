"""Byte images in colour spaces other than sRGB, Non-Color and the linear ones, converted to
scene linear by the transforms of Blender's OCIO config (addon/export/ocio.py), against Cycles
(which converts them with OpenColorIO at load; stored references, tests/cycles_refs/): a byte PNG
of saturated and grey texels on an emissive plane, one render per space."""
import numpy as np
import pytest

import bpy

from blender_util import Warnings, load_addon, render_to_array
from test_image_sources_cycles import render_both, uv_plane_scene, write_png

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.export.ocio import Unsupported, config_path, load_config, to_scene_linear  # noqa: E402

# 4 x 4 texels: saturated primaries and secondaries, greys, and mixes (sRGB-encoded bytes).
TEXELS = np.array([[(0.9, 0.1, 0.1), (0.1, 0.85, 0.15), (0.1, 0.2, 0.95), (0.95, 0.9, 0.1)],
                   [(0.05, 0.05, 0.05), (0.25, 0.25, 0.25), (0.5, 0.5, 0.5), (0.75, 0.75, 0.75)],
                   [(1.0, 1.0, 1.0), (0.6, 0.3, 0.8), (0.2, 0.7, 0.6), (0.8, 0.45, 0.2)],
                   [(0.0, 0.0, 0.0), (0.35, 0.6, 0.3), (0.9, 0.6, 0.7), (0.15, 0.3, 0.5)]], np.float32)

SPACES = ["Display P3", "Rec.1886", "Rec.2020", "ACEScg", "ACES2065-1", "Linear DCI-P3 D65",
          "Linear CIE-XYZ D65", "Filmic Log", "Filmic sRGB", "AgX Base sRGB", "AgX Log"]


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
    """Every colour space of Blender's config either converts (identities where the config says
    so: white stays white through a display space, the reference round-trips) or raises
    Unsupported naming what it lacks, never anything else."""
    config = load_config(config_path())
    names = {s["name"] for s in config["spaces"].values()}
    unsupported = {}
    white = np.ones((1, 3), np.float32)
    for name in sorted(names):
        if config["spaces"][name].get("isdata"):
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
    assert set(unsupported) <= {"Khronos PBR Neutral sRGB", "AgX False Color Rec.709", "AgX False Color P3",
                                "AgX False Color Rec.2020", "Luminance Compensation sRGB",
                                "Luminance Compensation P3", "Luminance Compensation Rec.2020"}, unsupported
    # sRGB through the config's ExponentWithLinear is the IEC curve Pathlight decodes in the core
    x = np.linspace(0.0, 1.0, 256, dtype=np.float32)[:, None].repeat(3, 1)
    iec = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    assert np.allclose(to_scene_linear(x, "sRGB"), iec, atol=2e-5)


def test_an_unsupported_space_warns_and_decodes_as_srgb(png):
    build = uv_plane_scene(image_in(png, "Khronos PBR Neutral sRGB"), (0.0, 0.0), (1.0, 1.0), 'Closest')
    build()
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert any("Khronos PBR Neutral sRGB" in w and "pbrNeutral.cube" in w for w in warnings), warnings


def test_byte_tables_and_merged_matrices_change_nothing():
    """to_scene_linear's shortcuts (byte values through a 256-entry table for the leading
    per-channel steps, runs of matrices merged into one) give what the transforms applied one
    by one give, on byte values and on others."""
    from addon.export.ocio import convert
    config = load_config(config_path())
    rng = np.random.default_rng(3)
    inputs = {"bytes": (rng.integers(0, 256, (500, 3)) / 255.0).astype(np.float32),
              "floats": rng.uniform(0.0, 1.0, (500, 3)).astype(np.float32)}
    checked = 0
    for name in sorted({s["name"] for s in config["spaces"].values() if not s.get("isdata")}):
        for what, x in inputs.items():
            try:
                fast = to_scene_linear(x, name)
            except Unsupported:
                continue
            slow = convert(x.astype(np.float64), name, "Linear Rec.709", config)
            assert np.allclose(fast, slow, rtol=1e-5, atol=1e-6), (name, what)
            checked += 1
    assert checked >= 2 * 18  # (19 spaces of Blender 4.5's config convert)
