"""Noise, Wave, Magic and White Noise textures against Cycles in the same bpy (issue 21).

Each image is a grid of unit planes seen by an orthographic camera from above, one texture
setup per plane, its output as the plane's emission (bounces=1, so a pixel is the emission
seen). Both engines use the box filter at its smallest width (0.01 px) and one sample, so
each pixel's sample lands within 0.005 px of its centre and the two images compare per pixel
(Cycles' later samples spread over the whole pixel whatever the box's width: measured, 4
samples differ from 1 by ~1e-3 on a smooth noise, so more samples would only add that);
plane edges lie on pixel boundaries. Outputs go through value * 0.25 + 2 (Math / Vector Math
Multiply Add, the same in both engines) so that negative or large values stay emissive: the
agreement limit (mean absolute difference under 1e-3 of the value range) is relative, so the
affine map leaves it unchanged.

What difference remains comes from where the samples land, not from the textures: Cycles'
single sample sits at the same place whatever the seed, ours within the 0.01 px box, and two
of our renders with different seeds differ from each other by as much as from Cycles (e.g.
1.25e-3 against 0.95e-3 of the range on Magic at distortion 2, 24 px planes). So setups keep
their features several pixels wide (32 px planes, moderate scales), where that stays under
the limit; at higher frequencies the same algorithms measure worse only through it."""

import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

PX = 32  # pixels per plane side
TINY_BOX = dict(pixel_filter_type='BOX', filter_width=0.01)


def _emit(mat, nodes, links, out, socket):
    """Emission of socket * 0.25 + 2 (a value or a colour)."""
    is_color = socket.type in ('RGBA', 'VECTOR')
    if is_color:
        m = nodes.new("ShaderNodeVectorMath")
        m.operation = 'MULTIPLY_ADD'
        m.inputs[1].default_value = (0.25, 0.25, 0.25)
        m.inputs[2].default_value = (2.0, 2.0, 2.0)
    else:
        m = nodes.new("ShaderNodeMath")
        m.operation = 'MULTIPLY_ADD'
        m.inputs[1].default_value = 0.25
        m.inputs[2].default_value = 2.0
    links.new(socket, m.inputs[0])
    em = nodes.new("ShaderNodeEmission")
    links.new(m.outputs[0], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])


def texture_material(name, node_type, output, settings=None, inputs=None, setup=None):
    """A material emitting `output` of one texture node with the given properties and inputs;
    setup(nodes, links, node) may link more."""
    mat, nodes, links, out = ms.new_material(name)
    node = nodes.new(node_type)
    for key, value in (settings or {}).items():
        setattr(node, key, value)
    by_id = {s.identifier: s for s in node.inputs}  # inputs[name] skips unavailable sockets
    for key, value in (inputs or {}).items():
        by_id[key].default_value = value
    if setup is not None:
        setup(nodes, links, node)
    _emit(mat, nodes, links, out, node.outputs[output])
    return mat


def grid_scene(make_materials, cols=None):
    """An empty scene with one unit plane per material of make_materials() in a grid, seen
    from above."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    materials = make_materials()
    n = len(materials)
    cols = cols or math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    for i, mat in enumerate(materials):
        r, c = divmod(i, cols)
        ms.add_plane(f"P{i}", 1.0, mat, location=(c - (cols - 1) / 2.0, (rows - 1) / 2.0 - r, 0.0))
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = float(max(cols, rows))
    cam.location = (0.0, 0.0, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x = cols * PX
    scene.render.resolution_y = rows * PX
    scene.render.resolution_percentage = 100
    return scene, rows, cols


def render_grid(make_materials, cols=None):
    """(Pathlight, Cycles, rows, cols) images of the grid of make_materials()' materials."""
    images = []
    for engine in ("PATHLIGHT", "CYCLES"):
        scene, rows, cols = grid_scene(make_materials, cols)
        images.append(render_to_array(scene, engine, samples=1, max_bounces=1, **TINY_BOX))
    return images[0], images[1], rows, cols


def cell(img, i, rows, cols):
    r, c = divmod(i, cols)
    return img[r * PX:(r + 1) * PX, c * PX:(c + 1) * PX, :3]


def assert_cells_agree(ours, cycles, rows, cols, labels, limit=1e-3):
    """Per plane: the mean absolute difference under `limit` of the plane's value range (at
    least the map's 0.25 of a unit range's tenth, so a flat plane is not divided by ~0)."""
    report = []
    for i, label in enumerate(labels):
        a, b = cell(ours, i, rows, cols), cell(cycles, i, rows, cols)
        assert np.isfinite(a).all(), label
        assert b.min() > 0.0, f"{label}: Cycles' output left the emissive range"
        value_range = max(float(b.max() - b.min()), 0.025)
        err = float(np.abs(a - b).mean()) / value_range
        report.append((label, err, value_range / 0.25))
    for label, err, value_range in report:  # the measured agreement, with -s
        print(f"  {label}: {err:.2e} of range {value_range:.3f}")
    bad = [r for r in report if not r[1] < limit]
    assert not bad, "\n".join(f"{l}: {e:.2e} of range {v:.3f}" for l, e, v in report)
    return report


def noise(name, output="Fac", dims="3D", ntype='FBM', normalize=True, setup=None, **inputs):
    base = {"Scale": 2.0, "Detail": 2.5, "Roughness": 0.6, "Lacunarity": 2.2, "W": 0.37}
    base.update(inputs)
    if dims == "1D" and setup is None:  # W across the plane (1D noise reads nothing else)
        def setup(nodes, links, node):
            w = _math(nodes, links, 'MULTIPLY', _generated_component(nodes, links, "X"), 1.5)
            links.new(_math(nodes, links, 'ADD', w, 0.2), {s.identifier: s for s in node.inputs}["W"])
    return texture_material(name, "ShaderNodeTexNoise", output,
                            dict(noise_dimensions=dims, noise_type=ntype, normalize=normalize),
                            base, setup)


def check(make, labels, cols=None, limit=1e-3):
    ours, cycles, rows, cols = render_grid(make, cols)
    return assert_cells_agree(ours, cycles, rows, cols, labels, limit)


DIMS = ("1D", "2D", "3D", "4D")


def test_noise_fbm_dimensions_normalize_distortion_color():
    variants = (("normalized", {}), ("raw", dict(normalize=False)),
                ("distorted", dict(Distortion=0.7)), ("color", dict(output="Color")))
    labels = [f"fBM {d} {v}" for d in DIMS for v, _ in variants]

    def make():
        return [noise(f"N{d}{v}", dims=d, **kw) for d in DIMS for v, kw in variants]
    check(make, labels, cols=4)


FRACTALS = (("MULTIFRACTAL", dict(Roughness=0.5)),
            ("HETERO_TERRAIN", dict(Offset=0.5, Roughness=0.5)),
            ("HYBRID_MULTIFRACTAL", dict(Offset=0.7, Gain=1.2)),
            ("RIDGED_MULTIFRACTAL", dict(Offset=1.0, Gain=2.0, Detail=3.0)))


def test_noise_fractal_types_in_every_dimension():
    labels = [f"{t} {d}" for t, _ in FRACTALS for d in DIMS]

    def make():
        return [noise(f"F{t}{d}", dims=d, ntype=t, Detail=kw.pop("Detail", 3.3), **kw)
                for t, kw0 in FRACTALS for d in DIMS for kw in (dict(kw0),)]
    check(make, labels, cols=4)


def test_noise_fractal_types_distortion_and_color():
    labels = [f"{t} {x}" for t, _ in FRACTALS for x in ("distorted 2D", "color 3D")]

    def make():
        out = []
        for t, kw in FRACTALS:
            out.append(noise(f"D{t}", dims="2D", ntype=t, Distortion=0.5, **kw))
            out.append(noise(f"C{t}", output="Color", dims="3D", ntype=t, **kw))
        return out
    check(make, labels, cols=4)


def _generated_component(nodes, links, axis):
    coords = nodes.new("ShaderNodeTexCoord")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coords.outputs["Generated"], sep.inputs[0])
    return sep.outputs[axis]


def _math(nodes, links, op, a, b):
    m = nodes.new("ShaderNodeMath")
    m.operation = op
    for i, v in enumerate((a, b)):
        if isinstance(v, (int, float)):
            m.inputs[i].default_value = v
        else:
            links.new(v, m.inputs[i])
    return m.outputs[0]


def _link_input(name, lo, span, axis="X"):
    """A setup linking input `name` to lo + span * (a generated coordinate)."""
    def setup(nodes, links, node):
        v = _math(nodes, links, 'MULTIPLY', _generated_component(nodes, links, axis), span)
        v = _math(nodes, links, 'ADD', v, lo)
        links.new(v, {s.identifier: s for s in node.inputs}[name])
    return setup


def _far_vector(nodes, links, node):
    """Generated coordinates moved far out (Cycles repeats noise every 100000 per axis)."""
    coords = nodes.new("ShaderNodeTexCoord")
    add = nodes.new("ShaderNodeVectorMath")
    add.inputs[1].default_value = (250000.3, -180000.7, 33333.3)
    links.new(coords.outputs["Generated"], add.inputs[0])
    links.new(add.outputs[0], node.inputs["Vector"])


def test_noise_linked_inputs():
    """Every input linked from the shading point (Scale, W, Detail, Roughness, Lacunarity,
    Offset, Gain, Distortion, and Vector from Object coordinates through a Mapping), and
    coordinates far from the origin."""
    link = _link_input

    def vector_setup(nodes, links, node):
        coords = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Location"].default_value = (0.3, -0.2, 0.1)
        mapping.inputs["Rotation"].default_value = (0.2, 0.1, 0.4)
        mapping.inputs["Scale"].default_value = (1.5, 1.0, 0.7)
        links.new(coords.outputs["Object"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], node.inputs["Vector"])

    cases = (("scale", {}, link("Scale", 1.0, 2.0)),
             ("w 1D", dict(dims="1D"), link("W", 0.0, 3.0)),
             ("w 4D", dict(dims="4D"), link("W", 0.0, 1.5, "Y")),
             ("detail", {}, link("Detail", 0.0, 4.0)),
             ("roughness", {}, link("Roughness", 0.2, 0.7, "Y")),
             ("lacunarity", {}, link("Lacunarity", 1.5, 1.5)),
             ("offset", dict(ntype='HETERO_TERRAIN', Roughness=0.5), link("Offset", 0.0, 1.0)),
             ("gain", dict(ntype='RIDGED_MULTIFRACTAL', Offset=1.0), link("Gain", 0.5, 2.0, "Y")),
             ("distortion", {}, link("Distortion", 0.0, 2.0)),
             ("vector", {}, vector_setup),
             ("far vector", dict(Scale=1.0, Detail=1.0), _far_vector))
    labels = [c[0] for c in cases]

    def make():
        return [noise(f"L{label}", setup=setup, **kw) for label, kw, setup in cases]
    check(make, labels, cols=5)


BANDS = ("X", "Y", "Z", "DIAGONAL")
RINGS = ("X", "Y", "Z", "SPHERICAL")
PROFILES = ("SIN", "SAW", "TRI")


def wave(name, wave_type, direction, profile, output="Fac", setup=None, **inputs):
    base = {"Scale": 0.8, "Distortion": 0.0, "Detail": 2.0, "Detail Scale": 1.0,
            "Detail Roughness": 0.5, "Phase Offset": 0.0}
    base.update(inputs)
    settings = dict(wave_type=wave_type, wave_profile=profile)
    settings["bands_direction" if wave_type == 'BANDS' else "rings_direction"] = direction
    return texture_material(name, "ShaderNodeTexWave", output, settings, base, setup)


def test_wave_bands_and_rings_every_direction_and_profile():
    cases = [(t, d, p) for t, dirs in (('BANDS', BANDS), ('RINGS', RINGS)) for d in dirs
             for p in PROFILES]
    labels = [" ".join(c) for c in cases]

    def make():
        # The plane's generated z is constant: Z bands and rings read coordinates tilted by
        # a Mapping, the others the unlinked (Generated) Vector.
        return [wave(f"W{i}", *c, setup=_tilted_vector if c[1] == "Z" else None,
                     **{"Phase Offset": 0.4, "Scale": 0.5 if c[1] == "Z" else 0.8})
                for i, c in enumerate(cases)]
    check(make, labels, cols=6)


def test_wave_distortion_detail_phase_and_color():
    cases = (("bands distorted", ('BANDS', "X", 'SIN'), dict(Distortion=4.0)),
             ("bands detail", ('BANDS', "DIAGONAL", 'TRI'),
              {"Distortion": 3.0, "Detail": 4.5, "Detail Scale": 2.0, "Detail Roughness": 0.7}),
             ("rings distorted", ('RINGS', "SPHERICAL", 'SAW'),
              {"Distortion": 2.0, "Detail": 0.0, "Detail Scale": 3.0}),
             ("rings phase", ('RINGS', "Z", 'SIN'), {"Phase Offset": 2.5, "Scale": 1.3}),
             ("color", ('BANDS', "Y", 'SIN'), dict(output="Color", Distortion=1.0)),
             ("linked scale", ('BANDS', "X", 'TRI'), dict(setup=_linked_wave_scale)))
    labels = [c[0] for c in cases]

    def make():
        return [wave(f"V{i}", *args, **dict(kw)) for i, (_, args, kw) in enumerate(cases)]
    check(make, labels, cols=3)


def _tilted_vector(nodes, links, node):
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.7, 0.4, 0.0)
    links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], node.inputs["Vector"])


def _linked_wave_scale(nodes, links, node):
    links.new(_math(nodes, links, 'ADD', _generated_component(nodes, links, "Y"), 0.5),
              node.inputs["Scale"])


def test_wave_and_magic_linked_inputs():
    link = _link_input
    cases = (("wave distortion", lambda: wave("LW0", 'BANDS', "X", 'SIN', Detail=2.0,
                                              setup=link("Distortion", 0.0, 4.0, "Y"))),
             ("wave detail", lambda: wave("LW1", 'BANDS', "DIAGONAL", 'TRI', Distortion=3.0,
                                          setup=link("Detail", 0.0, 5.0))),
             ("wave detail scale", lambda: wave("LW2", 'RINGS', "SPHERICAL", 'SIN', Distortion=2.0,
                                                setup=link("Detail Scale", 0.5, 2.0, "Y"))),
             ("wave detail roughness", lambda: wave(
                 "LW3", 'RINGS', "X", 'TRI', Distortion=2.0, Detail=3.0,
                 setup=link("Detail Roughness", 0.2, 0.8))),
             ("wave phase", lambda: wave("LW4", 'BANDS', "Y", 'SAW',
                                         setup=link("Phase Offset", 0.0, 3.0))),
             ("wave vector", lambda: wave("LW5", 'RINGS', "Z", 'SIN', Scale=0.5,
                                          setup=_tilted_vector)),
             ("magic scale", lambda: _linked_magic("LM0", link("Scale", 0.5, 1.0, "Y"))),
             ("magic distortion", lambda: _linked_magic("LM1", link("Distortion", 0.5, 1.5))),
             ("magic vector", lambda: _linked_magic("LM2", _tilted_vector)))
    labels = [c[0] for c in cases]

    def make():
        return [build() for _, build in cases]
    check(make, labels, cols=3)


def _linked_magic(name, setup):
    return texture_material(name, "ShaderNodeTexMagic", "Color", dict(turbulence_depth=3),
                            {"Scale": 1.0, "Distortion": 1.0}, setup)


def magic(name, depth, output="Fac", **inputs):
    base = {"Scale": 1.0, "Distortion": 1.0}
    base.update(inputs)
    return texture_material(name, "ShaderNodeTexMagic", output, dict(turbulence_depth=depth),
                            base)


def test_magic_depths_distortion_and_color():
    cases = [(f"depth {d}", d, {}) for d in range(11)]
    cases += [("color depth 2", 2, dict(output="Color")),
              ("color depth 5", 5, dict(output="Color", Distortion=2.0, Scale=0.5)),
              ("no distortion", 0, dict(Distortion=0.0, Scale=0.7)),
              ("distortion 3", 4, dict(Distortion=3.0, Scale=0.4)),
              ("scale 2", 1, dict(Scale=2.0))]
    labels = [c[0] for c in cases]

    def make():
        return [magic(f"M{i}", d, **kw) for i, (_, d, kw) in enumerate(cases)]
    check(make, labels, cols=4)


def test_white_noise_every_dimension_value_and_color():
    """White noise hashes the coordinates' bits: fed snapped coordinates (Vector Math Snap,
    Math Floor for W), each cell has one value, the same in both engines."""
    def setup(dims):
        def f(nodes, links, node):
            coords = nodes.new("ShaderNodeTexCoord")
            snap = nodes.new("ShaderNodeVectorMath")
            snap.operation = 'SNAP'
            snap.inputs[1].default_value = (0.125, 0.125, 0.125)
            # Off the cell edges: the plane's generated z (0.5, give or take the hit point's
            # rounding) would otherwise sit on a cell boundary.
            shift = nodes.new("ShaderNodeVectorMath")
            shift.inputs[1].default_value = (0.03, 0.03, 0.03)
            links.new(coords.outputs["Generated"], shift.inputs[0])
            links.new(shift.outputs[0], snap.inputs[0])
            links.new(snap.outputs[0], {s.identifier: s for s in node.inputs}["Vector"])
            w = _math(nodes, links, 'FLOOR',
                      _math(nodes, links, 'MULTIPLY', _generated_component(nodes, links, "X"),
                            6.0), 0.0)
            links.new(w, {s.identifier: s for s in node.inputs}["W"])
        return f

    cases = [(d, out, True) for d in DIMS for out in ("Value", "Color")]
    # Unlinked, the Vector is (0, 0, 0) in Cycles (no implicit coordinates): one colour.
    cases += [("3D", "Color", False), ("4D", "Value", False)]
    labels = [f"{d} {out}" + ("" if linked else " unlinked") for d, out, linked in cases]

    def make():
        return [texture_material(f"WN{i}", "ShaderNodeTexWhiteNoise", out,
                                 dict(noise_dimensions=d), {"W": 0.3},
                                 setup(d) if linked else None)
                for i, (d, out, linked) in enumerate(cases)]
    check(make, labels, cols=5)


# ---------------------------------------------------------------- the compiled programs

def _compile(mat):
    from addon.export.material import convert_material
    from blender_util import Warnings
    warnings = Warnings()
    data = convert_material(mat, warnings, None, None, False)
    return data.program, warnings


def _ops(program, name):
    return [op for op in program if op[0] == name]


def test_compiled_ops_read_generated_coordinates_and_warn_nothing():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    for node_type, op, output in (("ShaderNodeTexNoise", "tex_noise", "Color"),
                                  ("ShaderNodeTexWave", "tex_wave", "Fac"),
                                  ("ShaderNodeTexMagic", "tex_magic", "Color")):
        program, warnings = _compile(texture_material(op, node_type, output))
        assert not warnings, warnings
        (tex,) = _ops(program, op)
        # The unlinked Vector: Generated coordinates (registers are allocated by now, so the
        # op that writes the texture's vector register last before it).
        writer = [o for o in program[:program.index(tex)] if o[0] != "closure" and o[1] == tex[2]]
        assert writer[-1][0] == "generated", program
    # The node's own Texture Mapping (sidebar) is ignored, with a warning.
    mat = texture_material("Mapped", "ShaderNodeTexWave", "Fac")
    next(n for n in mat.node_tree.nodes if n.type == 'TEX_WAVE').texture_mapping.scale[0] = 2.0
    program, warnings = _compile(mat)
    assert len(warnings) == 1 and "Texture Mapping" in warnings[0], warnings
    # 1D noise reads only W: no coordinates, so a constant W leaves the program non-varying.
    program, warnings = _compile(noise("N1", dims="1D", setup=lambda *links: None))
    assert not warnings and not _ops(program, "generated")
    assert _ops(program, "tex_noise")[0][2] is None
    # White Noise's unlinked Vector is (0, 0, 0), as in Cycles (no implicit coordinates).
    program, warnings = _compile(texture_material("WN", "ShaderNodeTexWhiteNoise", "Value"))
    assert not warnings and not _ops(program, "generated")
    (tex,) = _ops(program, "tex_white_noise")
    vec = [o for o in program[:program.index(tex)] if o[0] != "closure" and o[1] == tex[2]][-1]
    assert vec[0] == "const" and tuple(vec[2][:3]) == (0.0, 0.0, 0.0)


def test_constant_inputs_are_not_folded_and_bump_offsets_reach_the_texture():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    mat, nodes, links, out = ms.new_material("Bumpy")
    tex = nodes.new("ShaderNodeTexNoise")
    bump = nodes.new("ShaderNodeBump")
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(tex.outputs["Fac"], bump.inputs["Height"])
    links.new(bump.outputs["Normal"], d.inputs["Normal"])
    links.new(d.outputs[0], out.inputs["Surface"])
    program, warnings = _compile(mat)
    assert not warnings, warnings
    # The height at the point and at the two offsets: three texture ops on three coordinates.
    assert len(_ops(program, "tex_noise")) == 3
    assert sorted(op[2:] for op in _ops(program, "generated")) == [(), (1,), (2,)]
    # A texture of constants is still emitted (the core evaluates it once).
    program, _ = _compile(noise("Const", dims="1D", setup=lambda *links: None))
    assert len(_ops(program, "tex_noise")) == 1


# ---------------------------------------------------------------- the core's ops

def _core_emission(ops, out):
    """(emission at the image centre, scene features) of a program on a plane."""
    from core_scenes import camera, core, quad, render
    pc = core()
    s = pc.Scene()
    m = s.add_shader("tex", list(ops) + [("closure", "emission", None, {"color": out})])
    pos, tris = quad((-5, 0, -5), (10, 0, 0), (0, 0, 10))
    s.add_instance(s.add_mesh(pos, tris, None, None, [m]), np.eye(4, dtype=np.float32))
    s.set_camera(camera(pc, (0, -20, 0), (0, 0, 0)))
    img, _ = render(pc, s, 8, 8, samples=1)
    return img[4, 4, :3], s.stats()["features"]


def _noise_op(dst, dims, ntype="FBM", color=False):
    return ("tex_noise", dst, 0, 1, 2, 3, 4, 5, 6, 7, 8, dims, ntype, True, color)


def _noise_inputs(vector=(0.3, 0.6, 0.2), w=0.37, scale=2.0, detail=2.5, roughness=0.6,
                  lacunarity=2.2, offset=0.0, gain=1.0, distortion=0.0):
    values = (vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion)
    return [("const", i, tuple(v) if isinstance(v, tuple) else (v,)) for i, v in enumerate(values)]


def test_core_texture_of_constants_is_evaluated_once():
    """A texture of constant inputs does not make the program varying (its closures are
    cached once); the value depends on the inputs the mode reads and on nothing else."""
    base, features = _core_emission(_noise_inputs() + [_noise_op(9, 3, color=True)], 9)
    assert "varying shaders" not in features and "mesh lights" in features
    assert np.isfinite(base).all() and 0.0 < base.min() and len(set(base.tolist())) == 3
    same, _ = _core_emission(_noise_inputs(w=5.0) + [_noise_op(9, 3, color=True)], 9)  # 3D: W unused
    assert (same == base).all()
    moved, _ = _core_emission(_noise_inputs(vector=(0.31, 0.6, 0.2)) + [_noise_op(9, 3, color=True)], 9)
    assert not (moved == base).all()
    w4, _ = _core_emission(_noise_inputs(w=5.0) + [_noise_op(9, 4, color=True)], 9)
    w4b, _ = _core_emission(_noise_inputs(w=5.3) + [_noise_op(9, 4, color=True)], 9)
    assert not (w4 == w4b).all()


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), 1e30, -1e30])
def test_core_textures_survive_non_finite_and_huge_inputs(bad):
    """Every input of every texture at NaN, infinities and huge values: no crash, no hang
    (Detail is bounded by the node's 15), and the emission the film gets stays finite."""
    programs = [_noise_inputs(vector=(bad, bad, bad), w=bad) + [_noise_op(9, d)] for d in (1, 2, 3, 4)]
    for field in ("scale", "detail", "roughness", "lacunarity", "offset", "gain", "distortion"):
        programs.append(_noise_inputs(**{field: bad}) + [_noise_op(9, 3, "HYBRID_MULTIFRACTAL")])
    consts = [("const", i, (bad,)) for i in range(7)]
    programs.append(consts + [("tex_wave", 9, 0, 1, 2, 3, 4, 5, 6, "RINGS", "SPHERICAL", "SAW")])
    programs.append(consts + [("tex_magic", 9, 0, 1, 2, 10, True)])
    programs.append(consts + [("tex_white_noise", 9, 0, 1, 4, True)])
    for ops in programs:
        value, _ = _core_emission(ops, 9)
        assert np.isfinite(value).all(), ops[-1]


# ---------------------------------------------------------------- Bump fed by a Noise

@pytest.mark.parametrize("scale, perspective, tol", [(4.0, False, 1e-3), (60.0, True, 3e-3)],
                         ids=["smooth", "fine-perspective"])
def test_bump_with_a_noise_height_matches_cycles(scale, perspective, tol):
    """A Bump node fed by a Noise texture on a lit diffuse plane, seen at the pixel centres.
    Both engines read the height Filter Width pixel footprints away (Cycles' ray differentials:
    the camera's pixel cone at the point), so even a noise finer than the pixels bumps the
    same, per pixel. (Before the footprints, a tiny fixed step gave 4.6e-3 of the range on the
    smooth noise.) The fine noise's finite differences over a tenth of a pixel lose a few
    float digits: 1.9e-3 of the range there."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        mat, nodes, links, out = ms.new_material("Bumped")
        tex = nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = scale
        tex.inputs["Detail"].default_value = 1.0
        bump = nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = 1.0
        bump.inputs["Distance"].default_value = 0.5 if scale < 10 else 0.05
        d = nodes.new("ShaderNodeBsdfDiffuse")
        links.new(tex.outputs["Fac"], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
        ms.add_plane("Ground", 2.0 if not perspective else 6.0, mat)
        sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
        sun.data.energy = 3.0
        sun.data.angle = 0.0
        sun.rotation_euler = (math.radians(50), 0.0, math.radians(30))
        scene.collection.objects.link(sun)
        if perspective:
            ms.add_camera((0.0, -3.0, 2.0), (0.0, 0.5, 0.0), lens=35.0)
        else:
            cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
            cam.data.type = 'ORTHO'
            cam.data.ortho_scale = 2.0
            cam.location = (0.0, 0.0, 5.0)
            scene.collection.objects.link(cam)
            scene.camera = cam
        scene.render.resolution_x = scene.render.resolution_y = 48
        scene.render.resolution_percentage = 100
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1, **TINY_BOX)[..., :3]
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=1, **TINY_BOX)[..., :3]
    flat = float(cycles.mean())
    print(f"bump: Cycles mean {flat:.4f}, std {float(cycles.std()):.4f}")
    assert flat > 0.05 and float(cycles.std()) > 0.05 * flat  # the bump shows
    ratio = float(ours.mean()) / flat
    per_pixel = float(np.abs(ours - cycles).mean()) / float(cycles.max() - cycles.min())
    corr = float(np.corrcoef(ours.mean(axis=2).ravel(), cycles.mean(axis=2).ravel())[0, 1])
    print(f"bump: mean ratio {ratio:.4f}, per-pixel MAD {per_pixel:.2e} of range, "
          f"correlation {corr:.4f}")
    assert abs(ratio - 1.0) < 0.005
    assert corr > 0.999
    assert per_pixel < tol
