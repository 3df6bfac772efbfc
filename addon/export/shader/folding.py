"""Constant folding and the op names: the core evaluates folded ops itself (pathlight_core
fold_constant: the renderer's float arithmetic), and its table of sub-operations
(shader_op_table) says which Math, Vector Math and Mix operations exist; plus the Ramp table
size and the Mapping matrix, which build op data."""

import functools
import math

import numpy as np

from ...core import get_core
from .values import Val, const_color, const_float, const_vector


@functools.lru_cache(maxsize=None)
def op_table():
    """The core's op table (core/scene/shader_ops.h): "ops" maps each value op to its register
    operand count; the sub-operation kinds map each name to a dict of operands, value_out and
    reads_scale."""
    table = get_core().shader_op_table()
    out = {kind: {e["name"]: e for e in entries} for kind, entries in table.items() if kind != "ops"}
    out["ops"] = dict(table["ops"])
    return out


def math_ops():
    return op_table()["math"]


def vector_math_ops():
    return op_table()["vector_math"]


def mix_blends():
    return op_table()["mix"]


def fold(kind, name, vals, *tail, alpha=None):
    """Op `name` on constant operands `vals` (then its literal arguments `tail`), evaluated by
    the core as the renderer would, as a constant of `kind` (a colour with `alpha` if given)."""
    program = [("const", i, tuple(v.const)) for i, v in enumerate(vals)]
    n = len(vals)
    program.append((name, n) + tuple(range(n)) + tuple(tail))
    out = get_core().fold_constant(program, n)
    if kind == "float":
        return const_float(out[0])
    if kind == "vector":
        return const_vector(out[:3])
    return const_color(out[:3] + (out[3] if alpha is None else alpha,))


def _sat(x):
    return min(max(x, 0.0), 1.0)


RAMP_TABLE_SIZE = 256  # Cycles' RAMP_TABLE_SIZE


def euler_matrix(xyz):
    """Blender's XYZ Euler rotation matrix (Rz @ Ry @ Rx), as the Mapping node uses."""
    x, y, z = (float(a) for a in xyz)
    cx, sx, cy, sy, cz, sz = math.cos(x), math.sin(x), math.cos(y), math.sin(y), math.cos(z), math.sin(z)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def mapping_matrix(vector_type, location, rotation, scale):
    """The 3x4 matrix of a Mapping node (Cycles' definitions): POINT T·R·S, TEXTURE its
    inverse S⁻¹·Rᵀ·(v − T), VECTOR R·S, NORMAL R·S⁻¹ (not normalised here)."""
    loc = np.asarray(location, np.float64)
    r = euler_matrix(rotation)
    s = np.asarray(scale, np.float64)
    safe_inv = np.array([1.0 / x if x != 0.0 else 0.0 for x in s])  # Cycles' safe_divide
    m = np.zeros((3, 4))
    if vector_type == 'POINT':
        m[:, :3] = r @ np.diag(s)
        m[:, 3] = loc
    elif vector_type == 'TEXTURE':
        m[:, :3] = np.diag(safe_inv) @ r.T
        m[:, 3] = -m[:, :3] @ loc
    elif vector_type == 'VECTOR':
        m[:, :3] = r @ np.diag(s)
    else:  # NORMAL
        m[:, :3] = r @ np.diag(safe_inv)
    return m.astype(np.float32)
