"""The second audit's compound scenes (artist_scenes.py, SCENES2: archviz daylight, foliage, a
night street, a stylised shot) against Cycles 4.5's stored references, as
test_artist_scenes_cycles.py: 64 x 48, 12 bounces, the 1-pixel box filter both sides, Pathlight
at 1024 samples against Cycles' 2048; the image mean within 1 %, every 8x8 region within 3 %,
the night street's within 4.5 % as the interior's: its measured seed noise (Pathlight 1024
against 1024, worst region 4.0 %: the haze lit by small lamps) leaves no room for 3 %
(docs/materials.md, "Compound scenes", second audit)."""

import functools

import pytest

from blender_util import core_available, load_addon
import artist_scenes as art
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

render_pair = functools.partial(ms.render_pair, bounces=12, cycles_samples=2048)


@pytest.mark.xfail(strict=True, reason="the translucent curtain beside the Glass/Transparent (Is Shadow "
                   "Ray) window pane is ~3 % brighter than Cycles' where it hangs in front of the wall "
                   "(region 3,4: +3.2 %, +2.3 % with another seed; Cycles against itself 0.4 %); "
                   "gone without the pane (test_archviz_open_window_matches_cycles), with a "
                   "plain Glass pane (no shadow-ray Transparent) or a diffuse curtain; cause not found yet (docs/materials.md, Known differences)")
def test_archviz_matches_cycles():
    ours, ref = render_pair(art.archviz, 1024)
    ms.assert_agree(ours, ref, "archviz")


def test_archviz_open_window_matches_cycles():
    """The control: the same room without the glass pane agrees."""
    ours, ref = render_pair(art.archviz_open_window, 1024)
    ms.assert_agree(ours, ref, "archviz, open window")


def test_foliage_matches_cycles():
    ours, ref = render_pair(art.foliage, 1024)
    ms.assert_agree(ours, ref, "foliage")


def test_night_street_matches_cycles():
    ours, ref = render_pair(art.night_street, 1024)
    ms.assert_agree(ours, ref, "night street", region=0.045)


def test_stylised_matches_cycles():
    ours, ref = render_pair(art.stylised, 1024)
    ms.assert_agree(ours, ref, "stylised")
