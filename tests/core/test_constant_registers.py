"""Programs whose value ops read nothing from the shading point (docs/materials.md, "Cost of the
default Principled"): their registers and their Principled inputs are made once at commit, and a
hit runs only the closure ops. The image must be the one the whole program gives per hit."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, render, uv_sphere

pc = core()

# Inputs for every part of PrincipledInputs: coat with tint, sheen, anisotropy turned, thin
# film, specular level and tint, diffuse roughness, metal, transmission, multiscatter, emission
# under the coat (subsurface in its own case).
PRINCIPLED = dict(base_color=(0.8, 0.5, 0.3), roughness=0.4, metallic=0.3, ior=1.45, transmission=0.2,
                  specular_level=0.7, specular_tint=(1.0, 0.8, 0.7), multiscatter=1.0, coat_weight=0.5,
                  coat_roughness=0.1, coat_ior=1.6, coat_tint=(0.9, 0.95, 1.0), sheen_weight=0.4,
                  sheen_roughness=0.3, sheen_tint=(1.0, 0.9, 0.9), anisotropic=0.5, anisotropic_rotation=0.1,
                  thin_film_thickness=300.0, thin_film_ior=1.4, diffuse_roughness=0.5,
                  emission=(0.2, 0.1, 0.05))


def program(reads_point, **inputs):
    """A Principled whose weight is the product of two constants (a Math op); with
    reads_point, an unused Position op makes the program read the point (the whole program runs
    per hit, the same values)."""
    prog = [("const", 0, (0.5,)), ("const", 1, (2.0,)), ("math", 2, 0, 1, "MULTIPLY", False)]
    regs = {}
    for i, (k, v) in enumerate(inputs.items(), start=3):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    if reads_point:
        prog.append(("position", 60))
    prog.append(("closure", "principled", 2, regs))
    return prog


def scene(prog):
    """A sphere of shader program `prog` on a grey floor, under a sky colour and a point light."""
    s = pc.Scene()
    m = s.add_shader("m", prog)
    floor = s.add_material("floor", base_color=(0.5, 0.5, 0.5))
    pos, tris, nrm = uv_sphere(1.0, nu=32, nv=16)
    add_object(s, pos, tris, m, nrm)
    p, t = quad((-4, -4, -1), (8, 0, 0), (0, 8, 0))
    add_object(s, p, t, floor)
    s.set_world_color((0.6, 0.7, 0.8))
    s.add_point_light((2.0, -3.0, 3.0), (40.0, 40.0, 40.0))
    s.set_camera(camera(pc, (0, -5, 1), (0, 0, 0), lens=50.0))
    return s, m


@pytest.mark.parametrize("inputs", [
    {"base_color": (0.8, 0.8, 0.8)},  # Blender's default material (multiscatter below)
    {"base_color": (0.8, 0.8, 0.8), "multiscatter": 1.0},
    PRINCIPLED,
    {**PRINCIPLED, "subsurface_weight": 0.5, "subsurface_radius": (1.0, 0.2, 0.1), "subsurface_scale": 0.1},
], ids=["default single", "default multiscatter", "every input", "subsurface"])
def test_registers_made_once_render_as_the_whole_program(inputs):
    images = {}
    for reads_point in (False, True):
        s, m = scene(program(reads_point, **inputs))
        s.commit()
        assert s.shader_evaluation(m) == ("program" if reads_point else "closures")
        img, stats = render(pc, s, 24, 24, samples=8, max_bounces=8, seed=3)
        assert stats["nonfinite_samples"] == 0
        images[reads_point] = img
    assert images[False][..., :3].mean() > 0.01
    np.testing.assert_array_equal(images[False], images[True])


def reused_program(reuse, last_reg=None, reads_point=False):
    """The add-on's allocator reuses registers: a Transparent closure reads r3 (0.6), then a
    Const writes r3 (0.4) for the Principled (with reuse; else r4). last_reg: a constant in that
    register too (63: no register left to rename into)."""
    w2 = 3 if reuse else 4
    prog = [("const", 5, (1.0, 1.0, 1.0)), ("const", 3, (0.6,)), ("closure", "transparent", 3, {"color": 5}),
            ("const", w2, (0.4,)), ("const", 6, (0.2, 0.6, 0.3)), ("const", 7, (1.0,)),
            ("closure", "principled", w2, {"base_color": 6, "multiscatter": 7})]
    if last_reg is not None:
        prog.insert(0, ("const", last_reg, (0.0,)))
    if reads_point:
        prog.append(("position", 60))
    return prog


@pytest.mark.parametrize("last_reg", [None, 63], ids=["renamed", "no register left"])
def test_a_register_reused_after_a_closure_read_it(last_reg):
    """Commit renames the later write apart, so each closure keeps its own inputs from commit
    and the image is the whole program's per hit; where no register is left to rename into, the
    program runs per hit."""
    images = {}
    for reuse, reads_point in ((True, False), (True, True), (False, False)):
        s, m = scene(reused_program(reuse, last_reg, reads_point))
        s.commit()
        cached = not reads_point and (last_reg is None or not reuse)
        assert s.shader_evaluation(m) == ("closures" if cached else "program")
        images[reuse, reads_point], _ = render(pc, s, 24, 24, samples=8, max_bounces=8, seed=3)
    assert images[True, False][..., :3].mean() > 0.01
    np.testing.assert_array_equal(images[True, False], images[True, True])
    np.testing.assert_array_equal(images[True, False], images[False, False])


def test_plain_diffuse_stays_constant_and_unknown_ids_raise():
    s = pc.Scene()
    m = s.add_material("grey", base_color=(0.5, 0.5, 0.5))
    assert s.shader_evaluation(m) == "constant"
    with pytest.raises(ValueError):
        s.shader_evaluation(99)
