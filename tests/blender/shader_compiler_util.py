"""What the shader compiler's tests share (test_shader_compiler.py, test_shader_compiler_values.py):
the autouse empty-scene fixture, compile_, a tiny interpreter of the constant part of the
program language (docs/core_api.md) and node helpers."""

import math

import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Vector

from blender_util import core_available, load_addon, Warnings
import material_scenes as ms

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402
from addon.export.material import MaterialTable, convert_material  # noqa: E402
from addon.export.shader import MAX_REGISTERS, ImageTable, UvSets, mapping_matrix  # noqa: E402
from shader_reference import _math, _mix  # noqa: E402


@pytest.fixture(autouse=True)
def empty_scene():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    yield


def compile_(mat, images=None, uv_sets=None, schlick=False):
    warnings = Warnings()
    data = convert_material(mat, warnings, images, uv_sets, schlick)
    assert len(warnings) <= 1, warnings  # at most ONE warning per material
    return data, warnings


# ---------------------------------------------------------------- a tiny interpreter

class Sym:
    """A value read from the shading point (uv, image, normal map...)."""

    def __init__(self, op):
        self.op = op

    def __repr__(self):
        return f"Sym({self.op[0]})"


def run(program):
    """Evaluates the constant part of a program: a list of (kind, weight rgb or None|Sym,
    {param: value 4-tuple | Sym}) closures, plus the register file."""
    regs = {}
    closures = []
    for op in program:
        name = op[0]
        if name == "closure":
            _, kind, w, params = op
            weight = None if w is None else regs[w]
            if not isinstance(weight, Sym) and weight is not None:
                weight = tuple(weight[:3])
            closures.append((kind, weight, {k: regs[v] for k, v in params.items()}))
            continue
        dst = op[1]
        if name == "const":
            regs[dst] = tuple(op[2])
        elif name == "math":
            a, b = regs[op[2]], regs[op[3]]
            if isinstance(a, Sym) or isinstance(b, Sym):
                regs[dst] = Sym(op)
            else:
                v = _math(op[4], a[0], b[0])
                v = min(max(v, 0.0), 1.0) if op[5] else v
                regs[dst] = (v, v, v, 1.0)
        elif name == "mix":
            f, a, b = regs[op[2]], regs[op[3]], regs[op[4]]
            if any(isinstance(x, Sym) for x in (f, a, b)):
                regs[dst] = Sym(op)
            else:
                fac = min(max(f[0], 0.0), 1.0)
                out = [_mix(op[5], x, y, fac) for x, y in zip(a[:3], b[:3])]
                if op[6]:
                    out = [min(max(x, 0.0), 1.0) for x in out]
                regs[dst] = tuple(out) + (a[3],)
        else:
            regs[dst] = Sym(op)
    return closures, regs


def closures_of(mat, **kw):
    data, warnings = compile_(mat, **kw)
    return run(data.program)[0], warnings, data


def weight_of(closure):
    return closure[1] if closure[1] is not None else (1.0, 1.0, 1.0)


# ---------------------------------------------------------------- node helpers

def link(tree, a, b):
    return tree.links.new(a, b)


def approx(x, rel=1e-5, abs=1e-6):
    return pytest.approx(x, rel=rel, abs=abs)
