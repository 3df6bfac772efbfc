"""Values of a shader program while it is compiled: constants (folded by the compiler) and
virtual registers, and the constants the translators share."""

import math
from dataclasses import dataclass

GREY = (0.8, 0.8, 0.8)
# Rec.709 luminance, as Blender's RGB to BW and colour → value conversions (scene linear).
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class Val:
    """A value of the program: a constant (folded here) or a virtual register.
    kind: 'float' (x = y = z, always broadcast), 'color' (rgb + alpha) or 'vector'."""
    kind: str
    const: tuple = None  # 4 floats, when constant
    reg: int = None

    @property
    def is_const(self):
        return self.const is not None


def const_float(x):
    x = float(x)
    if not math.isfinite(x):
        x = 0.0
    return Val("float", (x, x, x, 1.0))


def const_color(c):
    c = [float(v) if math.isfinite(float(v)) else 0.0 for v in c]
    return Val("color", (c[0], c[1], c[2], c[3] if len(c) > 3 else 1.0))


def const_vector(v):
    v = [float(x) if math.isfinite(float(x)) else 0.0 for x in v]
    return Val("vector", (v[0], v[1], v[2], 0.0))


ONE = const_float(1.0)
ZERO = const_float(0.0)
