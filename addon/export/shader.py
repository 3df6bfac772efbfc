"""Blender shader node trees → Pathlight shader programs (docs/core_api.md, issue 3).

A material's active output is walked from its Surface (and Volume) socket; value nodes become
register instructions, BSDF nodes become weighted closures. Constant sub-graphs are folded here,
so a material of constant inputs compiles to a few "const" ops and its closures.

Nothing here raises for a user's node tree: each unsupported node, link, setting or cycle is a
*problem*, noted with a fallback (documented at `_fallback_value` / `_fallback_shader`), and all
problems of one material are reported in ONE warning naming them.

The compiler uses virtual registers (unbounded) and a linear-scan allocation at the end maps
them onto the core's 64 registers.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from . import tex_patterns
from .image import is_srgb_bytes, read_pixels, rgb_of, to_scene_linear

MAX_REGISTERS = 64
MAX_UV_SETS = 8
GREY = (0.8, 0.8, 0.8)
# Rec.709 luminance, as Blender's RGB to BW and colour → value conversions (scene linear).
LUMA = (0.2126, 0.7152, 0.0722)
MISSING_TEXTURE = (1.0, 0.0, 1.0, 1.0)  # Cycles' magenta for an image that cannot be loaded

MATH_OPS = {"ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "POWER", "MINIMUM", "MAXIMUM",
            "LESS_THAN", "GREATER_THAN", "ABSOLUTE", "LOGARITHM", "SQRT", "INVERSE_SQRT",
            "EXPONENT", "SIGN", "ROUND", "FLOOR", "CEIL", "TRUNC", "FRACT", "MODULO",
            "FLOORED_MODULO", "SNAP", "PINGPONG", "SINE", "COSINE", "TANGENT", "ARCSINE",
            "ARCCOSINE", "ARCTANGENT", "ARCTAN2", "SINH", "COSH", "TANH", "RADIANS", "DEGREES",
            "MULTIPLY_ADD", "COMPARE", "SMOOTH_MIN", "SMOOTH_MAX", "WRAP"}
MATH_OPS_3 = {"MULTIPLY_ADD", "COMPARE", "SMOOTH_MIN", "SMOOTH_MAX", "WRAP"}  # read a third value
MIX_BLENDS = {"MIX", "MULTIPLY", "ADD", "SUBTRACT", "SCREEN", "DIVIDE", "DIFFERENCE", "DARKEN",
              "LIGHTEN", "OVERLAY"}


# ---------------------------------------------------------------- values

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


def _smooth_min(a, b, c):
    if c == 0.0:
        return min(a, b)
    h = max(c - abs(a - b), 0.0) / c
    return min(a, b) - h * h * h * c / 6.0


def _math(op, a, b, c=0.0):
    """The core's math op on floats (Blender's safe variants), for constant folding."""
    try:
        v = _math_unchecked(op, a, b, c)
    except (OverflowError, ValueError, ZeroDivisionError):
        v = 0.0
    return v if math.isfinite(v) else 0.0


_MATH_EXTRA = {
    "LOGARITHM": lambda a, b, c: (math.log(a) / math.log(b)
                                  if a > 0.0 and b > 0.0 and math.log(b) != 0.0 else 0.0),
    "SQRT": lambda a, b, c: math.sqrt(a) if a > 0.0 else 0.0,
    "INVERSE_SQRT": lambda a, b, c: 1.0 / math.sqrt(a) if a > 0.0 else 0.0,
    "EXPONENT": lambda a, b, c: math.exp(a),
    "SIGN": lambda a, b, c: 0.0 if a == 0.0 else math.copysign(1.0, a),
    "ROUND": lambda a, b, c: math.floor(a + 0.5),
    "FLOOR": lambda a, b, c: math.floor(a),
    "CEIL": lambda a, b, c: math.ceil(a),
    "TRUNC": lambda a, b, c: float(math.trunc(a)),
    "FRACT": lambda a, b, c: a - math.floor(a),
    "MODULO": lambda a, b, c: math.fmod(a, b) if b != 0.0 else 0.0,
    "FLOORED_MODULO": lambda a, b, c: a - math.floor(a / b) * b if b != 0.0 else 0.0,
    "SNAP": lambda a, b, c: math.floor(a / b) * b if b != 0.0 else 0.0,
    "PINGPONG": lambda a, b, c: (abs(((a - b) / (b * 2.0)) % 1.0 * b * 2.0 - b)
                                 if b != 0.0 else 0.0),
    "SINE": lambda a, b, c: math.sin(a),
    "COSINE": lambda a, b, c: math.cos(a),
    "TANGENT": lambda a, b, c: math.tan(a),
    "ARCSINE": lambda a, b, c: math.asin(min(max(a, -1.0), 1.0)),
    "ARCCOSINE": lambda a, b, c: math.acos(min(max(a, -1.0), 1.0)),
    "ARCTANGENT": lambda a, b, c: math.atan(a),
    "ARCTAN2": lambda a, b, c: math.atan2(a, b),
    "SINH": lambda a, b, c: math.sinh(a),
    "COSH": lambda a, b, c: math.cosh(a),
    "TANH": lambda a, b, c: math.tanh(a),
    "RADIANS": lambda a, b, c: a * math.pi / 180.0,
    "DEGREES": lambda a, b, c: a * 180.0 / math.pi,
    "MULTIPLY_ADD": lambda a, b, c: a * b + c,
    "COMPARE": lambda a, b, c: 1.0 if a == b or abs(a - b) <= max(c, 1.1920929e-7) else 0.0,
    "SMOOTH_MIN": _smooth_min,
    "SMOOTH_MAX": lambda a, b, c: -_smooth_min(-a, -b, c),
    "WRAP": lambda a, b, c: a - (b - c) * math.floor((a - c) / (b - c)) if b != c else c,
}


def _math_unchecked(op, a, b, c):
    if op in _MATH_EXTRA:
        return _MATH_EXTRA[op](a, b, c)
    if op == "ADD":
        v = a + b
    elif op == "SUBTRACT":
        v = a - b
    elif op == "MULTIPLY":
        v = a * b
    elif op == "DIVIDE":
        v = a / b if b != 0.0 else 0.0
    elif op == "POWER":
        if a >= 0.0:
            try:
                v = math.pow(a, b)
            except (OverflowError, ValueError, ZeroDivisionError):
                v = 0.0
        else:
            v = math.pow(a, b) if math.floor(b) == b else 0.0
    elif op == "MINIMUM":
        v = min(a, b)
    elif op == "MAXIMUM":
        v = max(a, b)
    elif op == "LESS_THAN":
        v = 1.0 if a < b else 0.0
    elif op == "GREATER_THAN":
        v = 1.0 if a > b else 0.0
    elif op == "ABSOLUTE":
        v = abs(a)
    else:
        raise ValueError(op)
    return v


def _mix(op, a, b, f):
    """The core's mix blend of one channel, for constant folding."""
    g = 1.0 - f
    if op == "MIX":
        return g * a + f * b
    if op == "MULTIPLY":
        return a * (g + f * b)
    if op == "ADD":
        return a + f * b
    if op == "SUBTRACT":
        return a - f * b
    if op == "SCREEN":
        return 1.0 - (g + f * (1.0 - b)) * (1.0 - a)
    if op == "DIVIDE":
        return g * a + f * a / b if b != 0.0 else a
    if op == "DIFFERENCE":
        return g * a + f * abs(a - b)
    if op == "DARKEN":
        return g * a + f * min(a, b)
    if op == "LIGHTEN":
        return g * a + f * max(a, b)
    if op == "OVERLAY":
        return a * (g + 2.0 * f * b) if a < 0.5 else 1.0 - (g + 2.0 * f * (1.0 - b)) * (1.0 - a)
    raise ValueError(op)


def _sat(x):
    return min(max(x, 0.0), 1.0)


RAMP_TABLE_SIZE = 256  # Cycles' RAMP_TABLE_SIZE
VECTOR_MATH_OPS = {"ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "CROSS_PRODUCT",
                   "PROJECT", "REFLECT", "REFRACT", "FACEFORWARD", "DOT_PRODUCT", "DISTANCE",
                   "LENGTH", "SCALE", "NORMALIZE", "ABSOLUTE", "POWER", "SIGN", "MINIMUM",
                   "MAXIMUM", "FLOOR", "CEIL", "FRACTION", "MODULO", "WRAP", "SNAP", "SINE",
                   "COSINE", "TANGENT"}
VECTOR_MATH_VALUE_OPS = {"DOT_PRODUCT", "DISTANCE", "LENGTH"}


def ramp_lookup(table, f, interpolate, extrapolate):
    """Cycles' rgb_ramp_lookup (the core's Ramp op), for constant folding."""
    n = len(table)
    if extrapolate and (f < 0.0 or f > 1.0):
        t0, t1 = (table[0], table[1]) if f < 0.0 else (table[-1], table[-2])
        k = (-f if f < 0.0 else f - 1.0) * (n - 1)
        return [a + (a - b) * k for a, b in zip(t0, t1)]
    f = _sat(f) * (n - 1) if math.isfinite(f) else 0.0
    i = min(max(int(f), 0), n - 1)
    w = f - i
    if interpolate and w > 0.0 and i + 1 < n:
        return [a + (b - a) * w for a, b in zip(table[i], table[i + 1])]
    return list(table[i])


def _rgb_to_hsv(c):
    r, g, b = c
    cmax, cmin = max(r, g, b), min(r, g, b)
    delta = cmax - cmin
    s = delta / cmax if cmax != 0.0 else 0.0
    h = 0.0
    if s != 0.0:
        cr, cg, cb = ((cmax - x) / delta for x in (r, g, b))
        h = (cb - cg) if r == cmax else (2.0 + cr - cb) if g == cmax else (4.0 + cg - cr)
        h /= 6.0
        if h < 0.0:
            h += 1.0
    return (h, s, cmax)


def _hsv_to_rgb(c):
    h, s, v = c
    if s == 0.0:
        return (v, v, v)
    if h == 1.0:
        h = 0.0
    h *= 6.0
    i = math.floor(h)
    f = h - i
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v)][int(i)] if 0 <= i < 5 \
        else (v, p, q)


def _rgb_to_hsl(c):
    r, g, b = c
    cmax, cmin = max(r, g, b), min(r, g, b)
    lum = min(1.0, (cmax + cmin) / 2.0)
    h = s = 0.0
    if cmax != cmin:
        d = cmax - cmin
        s = d / (2.0 - cmax - cmin) if lum > 0.5 else d / (cmax + cmin)
        if cmax == r:
            h = (g - b) / d + (6.0 if g < b else 0.0)
        elif cmax == g:
            h = (b - r) / d + 2.0
        else:
            h = (r - g) / d + 4.0
    return (h / 6.0, s, lum)


def _hsl_to_rgb(c):
    h, s, lum = c
    nr = _sat(abs(h * 6.0 - 3.0) - 1.0)
    ng = _sat(2.0 - abs(h * 6.0 - 2.0))
    nb = _sat(2.0 - abs(h * 6.0 - 4.0))
    chroma = (1.0 - abs(2.0 * lum - 1.0)) * s
    return tuple((x - 0.5) * chroma + lum for x in (nr, ng, nb))


_COLOR_SPACES = {"RGB_TO_HSV": _rgb_to_hsv, "HSV_TO_RGB": _hsv_to_rgb,
                 "RGB_TO_HSL": _rgb_to_hsl, "HSL_TO_RGB": _hsl_to_rgb}


def _hsv_node(color, hue, saturation, value, fac):
    """Cycles' svm_node_hsv."""
    h, s, v = _rgb_to_hsv(color)
    h = h + hue + 0.5
    out = _hsv_to_rgb((h - math.floor(h), _sat(s * saturation), v * value))
    return [max(fac * o + (1.0 - fac) * i, 0.0) for o, i in zip(out, color)]


def _gamma(color, g):
    if g == 0.0:
        return (1.0, 1.0, 1.0)
    out = []
    for x in color:
        try:
            y = math.pow(x, g) if x > 0.0 else x
        except (OverflowError, ValueError):
            y = 0.0
        out.append(y if math.isfinite(y) else 0.0)
    return out


def _clamp(v, lo, hi, clamp_type):
    if clamp_type == 'RANGE' and lo > hi:
        lo, hi = hi, lo
    return min(max(v, lo), hi)


def _smoothstep(e0, e1, x):
    if x < e0:
        return 0.0
    if x >= e1:
        return 1.0
    t = (x - e0) / (e1 - e0)
    return (3.0 - 2.0 * t) * t * t


def _smootherstep(e0, e1, x):
    x = _sat((x - e0) / (e1 - e0) if e1 != e0 else 0.0)
    return x * x * x * (x * (x * 6.0 - 15.0) + 10.0)


def _map_range(v, f0, f1, t0, t1, steps, mode, clamp):
    """Cycles' svm_node_map_range (float), with Blender's clamp of Linear and Stepped."""
    if f1 == f0:
        return 0.0
    if mode in ('LINEAR', 'STEPPED'):
        factor = (v - f0) / (f1 - f0)
        if mode == 'STEPPED':
            factor = math.floor(factor * (steps + 1.0)) / steps if steps > 0.0 else 0.0
    elif mode == 'SMOOTHSTEP':
        factor = 1.0 - _smoothstep(f1, f0, v) if f0 > f1 else _smoothstep(f0, f1, v)
    else:
        factor = 1.0 - _smootherstep(f1, f0, v) if f0 > f1 else _smootherstep(f0, f1, v)
    r = t0 + factor * (t1 - t0)
    if clamp and mode in ('LINEAR', 'STEPPED'):
        r = min(max(r, min(t0, t1)), max(t0, t1))
    return r if math.isfinite(r) else 0.0


def _map_range_vector(v, f0, f1, t0, t1, steps, mode, clamp):
    """Cycles' svm_node_vector_map_range: per component, with a safe division."""
    out = []
    for x, a, b, c, e, n in zip(v, f0, f1, t0, t1, steps):
        f = (x - a) / (b - a) if b != a else 0.0
        if mode == 'STEPPED':
            f = math.floor(f * (n + 1.0)) / n if n > 0.0 else 0.0
        elif mode == 'SMOOTHSTEP':
            f = _sat(f)
            f = (3.0 - 2.0 * f) * f * f
        elif mode == 'SMOOTHERSTEP':
            f = _sat(f)
            f = f * f * f * (f * (f * 6.0 - 15.0) + 10.0)
        r = c + f * (e - c)
        if clamp and mode in ('LINEAR', 'STEPPED'):
            r = min(max(r, min(c, e)), max(c, e))
        out.append(r if math.isfinite(r) else 0.0)
    return tuple(out)


def _vector_math(op, a, b, c, scale):
    """Blender's Vector Math on constants (the core's VectorMath op)."""
    a, b, c = (np.asarray(x, np.float64) for x in (a, b, c))
    safe_div = lambda x, y: np.where(y != 0.0, x / np.where(y != 0.0, y, 1.0), 0.0)  # noqa: E731
    with np.errstate(all='ignore'):
        if op == "DOT_PRODUCT":
            r = float(a @ b)
        elif op == "DISTANCE":
            r = float(np.linalg.norm(a - b))
        elif op == "LENGTH":
            r = float(np.linalg.norm(a))
        else:
            if op == "ADD":
                v = a + b
            elif op == "SUBTRACT":
                v = a - b
            elif op == "MULTIPLY":
                v = a * b
            elif op == "DIVIDE":
                v = safe_div(a, b)
            elif op == "MULTIPLY_ADD":
                v = a * b + c
            elif op == "CROSS_PRODUCT":
                v = np.cross(a, b)
            elif op == "PROJECT":
                bb = b @ b
                v = b * (a @ b) / bb if bb != 0.0 else np.zeros(3)
            elif op == "REFLECT":
                n = b / np.linalg.norm(b) if (b @ b) > 0.0 else None
                v = a if n is None else a - 2.0 * (a @ n) * n
            elif op == "REFRACT":
                n = b / np.linalg.norm(b) if (b @ b) > 0.0 else b
                d = n @ a
                k = 1.0 - scale * scale * (1.0 - d * d)
                v = np.zeros(3) if k < 0.0 else scale * a - (scale * d + math.sqrt(k)) * n
            elif op == "FACEFORWARD":
                v = a if (b @ c) < 0.0 else -a
            elif op == "SCALE":
                v = a * scale
            elif op == "NORMALIZE":
                ln = np.linalg.norm(a)
                v = a / ln if ln != 0.0 else np.zeros(3)
            elif op == "ABSOLUTE":
                v = np.abs(a)
            elif op == "POWER":
                v = np.array([_math("POWER", x, y) for x, y in zip(a, b)])
            elif op == "SIGN":
                v = np.sign(a)
            elif op == "MINIMUM":
                v = np.minimum(a, b)
            elif op == "MAXIMUM":
                v = np.maximum(a, b)
            elif op == "FLOOR":
                v = np.floor(a)
            elif op == "CEIL":
                v = np.ceil(a)
            elif op == "FRACTION":
                v = a - np.floor(a)
            elif op == "MODULO":
                v = np.where(b != 0.0, np.fmod(a, np.where(b != 0.0, b, 1.0)), 0.0)
            elif op == "WRAP":
                rng = b - c
                v = np.where(rng != 0.0, a - rng * np.floor((a - c) / np.where(rng != 0.0, rng, 1.0)), c)
            elif op == "SNAP":
                v = np.floor(safe_div(a, b)) * b
            elif op == "SINE":
                v = np.sin(a)
            elif op == "COSINE":
                v = np.cos(a)
            elif op == "TANGENT":
                v = np.tan(a)
            else:
                raise ValueError(op)
            v = np.where(np.isfinite(v), v, 0.0)
            return tuple(float(x) for x in v)
    return r if math.isfinite(r) else 0.0


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


# ---------------------------------------------------------------- scene-wide tables

class UvSets:
    """Global uv-set indices of UV map names across the scene; "" = each mesh's active render
    UV map."""

    def __init__(self):
        self.names = []  # index k -> name

    def index(self, name):
        """k for `name`, or None when all MAX_UV_SETS are taken."""
        name = name or ""
        if name in self.names:
            return self.names.index(name)
        if len(self.names) >= MAX_UV_SETS:
            return None
        self.names.append(name)
        return len(self.names) - 1


@dataclass
class ImageData:
    name: str
    pixels: np.ndarray  # float32 (H, W, 4) RGBA, row 0 = bottom: scene linear, or sRGB-encoded
    srgb: bool = False  # pixels hold sRGB-encoded colour, decoded by the core after filtering


@dataclass
class _LoadedImage:
    assoc: np.ndarray  # float32 (H, W, 4): colour multiplied by alpha, as Cycles stores it
    has_alpha: bool  # any alpha below 1
    unassociate: bool = True  # False: colour and alpha independent (data, channel packed)
    srgb: bool = False  # assoc holds 8-bit sRGB-encoded colour (byte/255), associated in bytes
    indices: dict = field(default_factory=dict)  # variant -> index in ImageTable.images


class ImageTable:
    """Images of the scene, each bpy Image read once (cached by pointer). Each variant of an
    image that programs use becomes one ImageData: "color" (the texels as Cycles stores them:
    associated alpha; the Color output divides by the filtered alpha when the Alpha output is
    linked, an operand of the image op) and "alpha" (the alpha in all four channels, so that it
    reads as a float register)."""

    def __init__(self):
        self.images = []  # ImageData, indexed by the program's image operands
        self._loaded = {}  # image pointer -> _LoadedImage or None (unreadable)

    def load(self, image, problems):
        """_LoadedImage or None; what went wrong reading it is added to `problems` (at each
        call: each material using the image hears about it)."""
        key = image.as_pointer()
        if key not in self._loaded:
            notes = []
            self._loaded[key] = (_load_image(image, notes), notes)
        loaded, notes = self._loaded[key]
        problems.extend(n for n in notes if n not in problems)
        return loaded

    def index(self, image, loaded, variant):
        if variant not in loaded.indices:
            if variant == "alpha":
                a = loaded.assoc[..., 3:4]
                pixels, srgb = np.ascontiguousarray(np.repeat(a, 4, axis=2)), False
            else:
                pixels, srgb = loaded.assoc, loaded.srgb
            loaded.indices[variant] = len(self.images)
            suffix = "" if variant == "color" else f" ({variant})"
            self.images.append(ImageData(image.name + suffix, pixels, srgb))
        return loaded.indices[variant]


def _load_image(image, problems):
    """_LoadedImage for a bpy Image, or None with a problem noted. Blender gives float images
    (.exr, .hdr) in scene linear with associated alpha, and byte images as raw byte/255 values
    in the image's colour space with straight alpha (image.pixels does not convert byte
    images). As Cycles does: byte sRGB images stay sRGB-encoded bytes, associated in bytes
    ((c * a) / 255, integer), for the core to filter encoded and decode per lookup; other
    byte images are linearised here and associated; data images are never associated."""
    buf, why = read_pixels(image)
    if buf is None:
        problems.append(why + " (magenta)")
        return None
    height, width, channels = buf.shape
    rgb = rgb_of(buf)
    alpha = buf[..., 3] if channels == 4 else (buf[..., 1] if channels == 2 else None)
    alpha = np.ones((height, width), np.float32) if alpha is None else np.array(alpha)

    space = image.colorspace_settings
    is_data = space.is_data or space.name == "Non-Color"
    mode = image.alpha_mode
    associate = not is_data and mode not in {'CHANNEL_PACKED', 'NONE'}
    if is_srgb_bytes(image):
        if space.name != "sRGB":
            problems.append(f"colour space '{space.name}' of byte image '{image.name}' is not "
                            "supported (decoded as sRGB)")
        to_byte = lambda x: np.clip(np.round(np.nan_to_num(x) * 255.0), 0, 255).astype(np.uint32)  # noqa: E731
        c, a = to_byte(rgb), to_byte(alpha)
        if mode == 'NONE':
            a[:] = 255
        if associate:
            c = c * a[..., None] // 255
        assoc = np.concatenate([c, a[..., None]], axis=2).astype(np.float32) / np.float32(255.0)
        return _LoadedImage(np.ascontiguousarray(assoc), bool((a < 255).any()), associate, True)

    rgb, note = to_scene_linear(image, rgb)
    if note:
        problems.append(note)
    bad = ~np.isfinite(rgb)
    if bad.any() or (rgb < 0).any() and not is_data:
        rgb = np.where(bad, 0.0, rgb)
        if not is_data:
            np.maximum(rgb, 0.0, out=rgb)
    alpha = np.clip(np.nan_to_num(alpha, nan=1.0), 0.0, 1.0)
    if mode == 'NONE':
        alpha[:] = 1.0
    if associate and not image.is_float:  # byte images are straight; float ones associated
        rgb = rgb * alpha[..., None]
    assoc = np.ascontiguousarray(np.concatenate([rgb, alpha[..., None]], axis=2), np.float32)
    return _LoadedImage(assoc, bool((alpha < 1.0).any()), associate)


# ---------------------------------------------------------------- compiled material

@dataclass
class CompiledShader:
    program: list  # tuples of docs/core_api.md; image operands index ImageTable.images
    volume_absorption: tuple = None  # ((r, g, b), density) or None
    volume: dict = None  # the homogeneous medium (sigma_a, sigma_s, g, emission) or None
    # k -> UV map name this material reads, or for attribute sets (numbered with the uv sets)
    # ("attr", name) (the Attribute node) / ("color", name) (Color Attribute; "" = the render one).
    uv_sets: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)  # what was approximated/unsupported


class _Cycle(Exception):
    pass


def _fmt(x):
    return f"{x:g}"


class ShaderCompiler:
    """Compiles one material's node tree. Use `compile_material`."""

    def __init__(self, images, uv_sets, material_index=0):
        self.images = images
        self.uv_sets = uv_sets
        self.material_index = material_index  # the material's pass index (Object Info)
        self.ops = []  # with virtual registers
        self.nreg = 0
        self.const_regs = {}  # const tuple -> virtual register
        self.cache = {}  # (node ptr, output identifier, ctx key) -> Val
        self.visiting = set()
        self.problems = []
        self.uv_used = {}
        self._links = {}  # tree pointer -> {to_socket pointer: link}
        # Where reads of the shading point happen: 0 the point, 1 / 2 the Bump node's offsets
        # (its Height sub-graph is compiled once per offset, as Cycles duplicates it).
        self.bump_state = 0

    # -------------------------------------------------- problems

    def problem(self, msg):
        if msg not in self.problems:
            self.problems.append(msg)

    # -------------------------------------------------- registers

    def new_reg(self):
        self.nreg += 1
        return self.nreg - 1

    def reg(self, val):
        """The register holding `val` (constants are materialised once)."""
        if not val.is_const:
            return val.reg
        r = self.const_regs.get(val.const)
        if r is None:
            r = self.const_regs[val.const] = self.new_reg()
            self.ops.append(("const", r, val.const))
        return r

    def emit(self, kind, *args):
        r = self.new_reg()
        self.ops.append((args[0], r) + tuple(args[1:]))
        return Val(kind, reg=r)

    # -------------------------------------------------- conversions

    def as_float(self, v, what=""):
        if v.kind == "float":
            return v
        if v.is_const:
            if v.kind == "vector":  # Blender: the average of the components
                return const_float(sum(v.const[:3]) / 3.0)
            return const_float(sum(c * w for c, w in zip(v.const[:3], LUMA)))
        if v.kind == "vector":
            self.problem(f"vector-to-value conversion{what} approximated by luminance")
        return self.emit("float", "rgb_to_bw", self.reg(v))

    def as_color(self, v):
        if v.kind == "color":
            return v
        if v.is_const:
            c = v.const
            return Val("color", (c[0], c[1], c[2], 1.0))
        return Val("color", reg=v.reg)  # floats are broadcast, vectors reinterpreted

    def as_vector(self, v):
        if v.kind == "vector":
            return v
        if v.is_const:
            c = v.const
            return Val("vector", (c[0], c[1], c[2], 0.0))
        return Val("vector", reg=v.reg)

    def convert(self, v, kind, what=""):
        if kind == "float":
            return self.as_float(v, what)
        if kind == "vector":
            return self.as_vector(v)
        return self.as_color(v)

    # -------------------------------------------------- arithmetic (folded when constant)

    def math(self, op, a, b, clamp=False, c=None):
        a, b = self.as_float(a), self.as_float(b)
        c = ZERO if c is None else self.as_float(c)
        if a.is_const and b.is_const and c.is_const:
            v = _math(op, a.const[0], b.const[0], c.const[0])
            return const_float(_sat(v) if clamp else v)
        if op in MATH_OPS_3:
            return self.emit("float", "math3", self.reg(a), self.reg(b), self.reg(c), op,
                             bool(clamp))
        return self.emit("float", "math", self.reg(a), self.reg(b), op, bool(clamp))

    def mix(self, blend, fac, a, b, clamp=False, kind="color"):
        """The core's mix: fac (clamped to [0, 1]) in .x, per-channel blend of a and b."""
        fac = self.as_float(fac)
        a, b = self.convert(a, kind), self.convert(b, kind)
        if fac.is_const and a.is_const and b.is_const:
            f = _sat(fac.const[0])
            out = [_mix(blend, x, y, f) for x, y in zip(a.const[:3], b.const[:3])]
            if clamp:
                out = [_sat(x) for x in out]
            return Val(kind, tuple(x if math.isfinite(x) else 0.0 for x in out) + (a.const[3],))
        if fac.is_const and blend == "MIX" and not clamp:
            f = _sat(fac.const[0])
            if f == 0.0:
                return a
            if f == 1.0:
                return b
        return self.emit(kind, "mix", self.reg(fac), self.reg(a), self.reg(b), blend, bool(clamp))

    def scale(self, weight, s):
        """weight (colour) * s (float or colour), either None meaning 1."""
        if weight is None:
            return s
        if s is None:
            return weight
        if weight.is_const and all(x == 1.0 for x in weight.const[:3]):
            return self.as_color(s)
        if s.is_const and all(x == 1.0 for x in s.const[:3]):
            return weight
        return self.mix("MULTIPLY", ONE, weight, s)

    @staticmethod
    def is_zero(v):
        return v is not None and v.is_const and all(x == 0.0 for x in v.const[:3])

    # -------------------------------------------------- graph walking

    def link_into(self, socket):
        """The valid, unmuted link into an input socket, or None."""
        tree = socket.id_data
        key = tree.as_pointer()
        links = self._links.get(key)
        if links is None:
            links = self._links[key] = {}
            for link in tree.links:
                links.setdefault(link.to_socket.as_pointer(), link)
        link = links.get(socket.as_pointer())
        if link is None or link.is_muted:
            return None
        if not link.is_valid:
            self.problem(f"invalid link from '{link.from_node.name}' to "
                         f"'{link.to_node.name}' ({socket.name}) ignored")
            return None
        return link

    def source(self, socket, ctx):
        """What feeds input `socket` in group context ctx (a tuple of group nodes), through
        reroutes, muted nodes, node groups and their Group Input/Output:
        None (unconnected), ("default", socket) (an unconnected socket whose value applies) or
        ("node", node, output socket, ctx)."""
        link = self.link_into(socket)
        if link is None:
            return None
        node, out = link.from_node, link.from_socket
        for _ in range(10000):  # a reroute loop cannot hang us
            if node.type == 'REROUTE':
                link = self.link_into(node.inputs[0])
                if link is None:
                    return None
                node, out = link.from_node, link.from_socket
            elif node.mute:
                inner = [l for l in node.internal_links if l.to_socket == out]
                if not inner:
                    return None
                src = inner[0].from_socket
                link = self.link_into(src)
                if link is None:
                    return ("default", src)
                node, out = link.from_node, link.from_socket
            elif node.type == 'GROUP':
                tree = node.node_tree
                if tree is None:
                    self.problem(f"node group '{node.name}' has no node tree")
                    return None
                outputs = [n for n in tree.nodes if n.type == 'GROUP_OUTPUT']
                active = [n for n in outputs if n.is_active_output] or outputs
                if not active:
                    return None
                inner = next((s for s in active[0].inputs if s.identifier == out.identifier), None)
                if inner is None:
                    return None
                if len(ctx) > 32:
                    raise _Cycle(node.name)
                ctx = ctx + (node,)
                link = self.link_into(inner)
                if link is None:
                    return ("default", inner)
                node, out = link.from_node, link.from_socket
            elif node.type == 'GROUP_INPUT':
                if not ctx:
                    self.problem(f"Group Input '{node.name}' outside a node group")
                    return None
                group = ctx[-1]
                ctx = ctx[:-1]
                outer = next((s for s in group.inputs if s.identifier == out.identifier), None)
                if outer is None:
                    return None
                link = self.link_into(outer)
                if link is None:
                    return ("default", outer)
                node, out = link.from_node, link.from_socket
            else:
                return ("node", node, out, ctx)
        raise _Cycle(node.name)

    @staticmethod
    def ctx_key(ctx):
        return tuple(n.as_pointer() for n in ctx)

    # -------------------------------------------------- values of inputs

    def socket_default(self, socket, kind):
        """Val of an unconnected socket's own value, converted to `kind`."""
        dv = getattr(socket, "default_value", None)
        if dv is None:
            return {"float": ZERO, "color": const_color((0, 0, 0, 1)),
                    "vector": const_vector((0, 0, 0))}[kind]
        if isinstance(dv, (bool, int, float)):
            v = const_float(dv)
        else:
            vals = tuple(dv)
            v = const_color(vals) if len(vals) == 4 else const_vector(
                (vals + (0.0, 0.0, 0.0))[:3])
            if socket.type == 'RGBA':
                v = const_color(vals)
        return self.convert(v, kind)

    def value(self, socket, ctx, kind):
        """Val of input `socket` (linked or not) as `kind`. Returns None for an unconnected
        socket whose default is "implicit" (hidden-value vectors: Normal, image Vector...)."""
        src = self.source(socket, ctx)
        if src is None:
            if getattr(socket, "hide_value", False) and socket.type == 'VECTOR':
                return None
            return self.socket_default(socket, kind)
        if src[0] == "default":
            return self.socket_default(src[1], kind)
        _, node, out, nctx = src
        if out.type == 'SHADER':
            self.problem(f"shader output of '{node.name}' linked to a value input "
                         f"({socket.name}) ignored")
            return self.socket_default(socket, kind)
        v = self.node_output(node, out, nctx, socket, kind)
        if v is None:  # an implicit value (e.g. the shading normal)
            if getattr(socket, "hide_value", False) and socket.type == 'VECTOR':
                return None
            return self.socket_default(socket, kind)
        return self.convert(v, kind, f" into {socket.name}")

    def input(self, node, name, ctx, kind):
        return self.value(node.inputs[name], ctx, kind)

    def const_input(self, node, name, ctx, kind):
        """A constant input value (used where the core takes constants): a linked input is a
        problem, its socket's own value is used."""
        socket = node.inputs[name]
        v = self.value(socket, ctx, kind)
        if v is not None and v.is_const:
            return v
        self.problem(f"linked input {name} of '{node.name}' is not supported (its value is used)")
        return self.socket_default(socket, kind)

    def node_output(self, node, out, ctx, consumer, kind):
        key = (node.as_pointer(), out.identifier, self.ctx_key(ctx), self.bump_state)
        if key in self.cache:
            return self.cache[key]
        if key in self.visiting:
            raise _Cycle(node.name)
        self.visiting.add(key)
        try:
            v = self.eval_value_node(node, out, ctx)
        finally:
            self.visiting.discard(key)
        if v is NotImplemented:
            return self._fallback_value(node, ctx, consumer, kind)
        self.cache[key] = v
        return v

    def _fallback_value(self, node, ctx, consumer, kind):
        """An unsupported value node: its own Color input when it has one (linked or not),
        else the consumer socket's own value (None, the implicit value, for hidden vectors)."""
        color = node.inputs.get("Color")
        what = f"'{node.name}' ({node.bl_idname}) is not supported"
        if color is not None and kind == "color":
            self.problem(f"{what} (its Color input is used)")
            v = self.value(color, ctx, "color")
            return v if v is not None else self.socket_default(color, "color")
        if getattr(consumer, "hide_value", False) and consumer.type == 'VECTOR':
            self.problem(f"{what} (ignored)")
            return None
        self.problem(f"{what} (the value of {consumer.name} is used)")
        return self.socket_default(consumer, kind)

    # -------------------------------------------------- value nodes

    def uv(self, name, what):
        k = self.uv_sets.index(name)
        if k is None:
            self.problem(f"{what}: more than {MAX_UV_SETS} UV maps in the scene (UV map "
                         f"'{name}' reads as the first)")
            k = 0
        self.uv_used[k] = name or ""
        return k

    def uv_value(self, name, what):
        """Val of the UV coordinates of a UV map (one "uv" op per set)."""
        k = self.uv(name, what)
        key = ("uv", k, self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", "uv", k, *extra)
        return self.cache[key]

    def attribute_value(self, kind, name, output, what):
        """Val of a mesh attribute's output ("COLOR", "FAC" or "ALPHA"): kind "attr" (by name)
        or "color" (a colour attribute; "" = the mesh's render colour attribute)."""
        k = self.uv_sets.index((kind, name))
        if k is None:
            self.problem(f"{what}: more than {MAX_UV_SETS} UV maps and attributes in the scene "
                         "(reads 0)")
            return ZERO if output != "COLOR" else const_color((0, 0, 0, 0))
        self.uv_used[k] = (kind, name)
        key = ("attribute", k, output)
        if key not in self.cache:
            self.cache[key] = self.emit("float" if output != "COLOR" else "color", "attribute", k,
                                        output)
        return self.cache[key]

    def color_attribute(self, node, out, ctx):
        """Color Attribute: a colour attribute of the mesh (its render one when unnamed)."""
        output = "ALPHA" if out.identifier == "Alpha" else "COLOR"
        return self.attribute_value("color", node.layer_name, output, f"'{node.name}'")

    def attribute_node(self, node, out, ctx):
        """Attribute: a geometry attribute of the mesh by name (any domain but edges, any
        type: floats read as grey, 2D vectors with z = 0). Object, instancer and view-layer
        attributes are not supported (0)."""
        if node.attribute_type != 'GEOMETRY':
            self.problem(f"'{node.name}': {node.attribute_type.lower().replace('_', ' ')} "
                         "attributes are not supported (0)")
            return ZERO if out.identifier in ("Fac", "Alpha") else const_color((0, 0, 0, 1))
        if not node.attribute_name:
            return ZERO if out.identifier in ("Fac", "Alpha") else const_color((0, 0, 0, 1))
        output = {"Fac": "FAC", "Alpha": "ALPHA"}.get(out.identifier, "COLOR")
        v = self.attribute_value("attr", node.attribute_name, output, f"'{node.name}'")
        return Val("vector", reg=v.reg) if out.identifier == "Vector" else v

    def object_coords(self, which):
        """Val of the object-space ("object") or texture-space ("generated") position."""
        key = (which, self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", which, *extra)
        return self.cache[key]

    def position(self):
        """Val of the world position (at the current bump offset)."""
        key = ("position", self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", "position", *extra)
        return self.cache[key]

    def eval_value_node(self, node, out, ctx):
        t = node.type
        oid = out.identifier
        if t == 'RGB':
            return const_color(out.default_value)
        if t == 'VALUE':
            return const_float(out.default_value)
        if t == 'TEX_IMAGE':
            return self.image_texture(node, out, ctx)
        if t == 'TEX_COORD':
            return self.tex_coord(node, oid)
        if t == 'UVMAP':
            if node.from_instancer:
                self.problem(f"'{node.name}': UV from instancer is not supported")
            return self.uv_value(node.uv_map, f"'{node.name}'")
        if t == 'NEW_GEOMETRY':
            if oid == "Position":
                return self.position()
            if oid == "Normal":
                return self.emit("vector", "normal")
            if oid == "Tangent":  # Cycles: radial around the object's Z axis
                return self.emit("vector", "tangent", "Z", 0)
            if oid == "Pointiness":  # per vertex, computed at export as Cycles does
                return self.attribute_value("pointiness", "", "ALPHA", f"'{node.name}'")
            if oid == "Random Per Island":  # per triangle, computed at export as Cycles does
                return self.attribute_value("island", "", "ALPHA", f"'{node.name}'")
            which = self._GEOMETRY.get(oid)
            if which is not None:
                return self.emit("float" if oid == "Backfacing" else "vector", "geometry", which)
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO if out.type == 'VALUE' else const_vector((0, 0, 0))
        if t == 'MAPPING':
            return self.mapping(node, ctx)
        if t == 'MIX':
            return self.mix_node(node, oid, ctx)
        if t == 'MIX_RGB':
            return self.mix_color(node, node.blend_type, self.input(node, "Fac", ctx, "float"),
                                  self.input(node, "Color1", ctx, "color"),
                                  self.input(node, "Color2", ctx, "color"), node.use_clamp)
        if t == 'MATH':
            return self.math_node(node, ctx)
        if t == 'RGBTOBW':
            return self.as_float(self.input(node, "Color", ctx, "color"))
        if t == 'INVERT':
            fac = self.input(node, "Fac", ctx, "float")
            c = self.input(node, "Color", ctx, "color")
            inverted = self.mix("SUBTRACT", ONE, const_color((1, 1, 1, 1)), c)
            return self.mix("MIX", fac, c, inverted)
        if t == 'NORMAL_MAP':
            return self.normal_map(node, ctx)
        handler = self._VALUE_NODES.get(t)
        if handler is not None:
            return handler(self, node, out, ctx)
        return NotImplemented

    # -------------------------------------------------- more value nodes (issue 3)

    def fresnel_node(self, node, out, ctx):
        ior = self.input(node, "IOR", ctx, "float")
        normal = self.normal(node, ctx)
        return self.emit("float", "fresnel", self.reg(ior),
                         None if normal is None else self.reg(normal))

    def layer_weight(self, node, out, ctx):
        blend = self.input(node, "Blend", ctx, "float")
        normal = self.normal(node, ctx)
        which = "FACING" if out.identifier == "Facing" else "FRESNEL"
        return self.emit("float", "layer_weight", self.reg(blend),
                         None if normal is None else self.reg(normal), which)

    def bump(self, node, out, ctx):
        """Cycles' Bump: the height at the point and at two offsets Filter Width pixel
        footprints away (Cycles' ray differentials; one filter width per material)."""
        normal = self.normal(node, ctx)
        strength = self.input(node, "Strength", ctx, "float")
        distance = self.input(node, "Distance", ctx, "float")
        height = node.inputs["Height"]
        if self.source(height, ctx) is None or (strength.is_const and strength.const[0] <= 0.0):
            return normal  # nothing to differentiate: the input normal (None: the shading one)
        saved = self.bump_state
        heights = []
        try:
            for state in (0, 1, 2):
                self.bump_state = state
                heights.append(self.value(height, ctx, "float"))
        finally:
            self.bump_state = saved
        if all(h.is_const for h in heights):
            return normal  # a constant height has no slope
        width_socket = node.inputs.get("Filter Width")
        width = 0.1 if width_socket is None else self.const_input(node, "Filter Width", ctx, "float").const[0]
        first = self.cache.setdefault("bump_filter_width", width)
        if first != width:
            self.problem(f"'{node.name}': Filter Width {width:g} differs from another Bump's "
                         f"{first:g} in the material (that one is used)")
        return self.emit("vector", "bump", *(self.reg(h) for h in heights), self.reg(strength),
                         self.reg(distance), None if normal is None else self.reg(normal),
                         bool(node.invert), max(0.0, float(width)))

    _GEOMETRY = {"True Normal": "TRUE_NORMAL", "Incoming": "INCOMING",
                 "Parametric": "PARAMETRIC", "Backfacing": "BACKFACING"}

    def light_path(self, node, out, ctx):
        """Light Path: every output from the core's path state, as Cycles'."""
        which = out.identifier.upper().replace(" ", "_")
        if which not in self._LIGHT_PATH:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit("float", "light_path", which)

    _LIGHT_PATH = {"IS_CAMERA_RAY", "IS_SHADOW_RAY", "IS_DIFFUSE_RAY", "IS_GLOSSY_RAY",
                   "IS_SINGULAR_RAY", "IS_REFLECTION_RAY", "IS_TRANSMISSION_RAY",
                   "IS_VOLUME_SCATTER_RAY", "RAY_LENGTH",
                   "RAY_DEPTH", "DIFFUSE_DEPTH", "GLOSSY_DEPTH", "TRANSPARENT_DEPTH",
                   "TRANSMISSION_DEPTH"}

    _OBJECT_INFO = {"Location": ("vector", "LOCATION"), "Color": ("color", "COLOR"),
                    "Alpha": ("float", "ALPHA"), "Object Index": ("float", "OBJECT_INDEX"),
                    "Random": ("float", "RANDOM")}

    def object_info(self, node, out, ctx):
        """Object Info: the hit instance's location, colour, alpha, pass index and random
        number (per instance in the core); Material Index is this material's pass index."""
        if out.identifier == "Material Index":
            return const_float(float(self.material_index))
        kind, which = self._OBJECT_INFO.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit(kind, "object_info", which)

    _CURVES_INFO = {"Is Strand": ("float", "IS_STRAND"), "Intercept": ("float", "INTERCEPT"),
                    "Length": ("float", "LENGTH"), "Thickness": ("float", "THICKNESS"),
                    "Tangent Normal": ("vector", "TANGENT_NORMAL"), "Random": ("float", "RANDOM")}

    def curves_info(self, node, out, ctx):
        """Curves Info: what the hit strand's geometry says (zeros off curves, as Cycles)."""
        kind, which = self._CURVES_INFO.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit(kind, "curves_info", which)

    def ramp(self, src, table, interpolate, extrapolate=False, lo=0.0, hi=1.0, channels=False,
             kind="color"):
        if src.is_const:
            c = src.const
            rel = lambda v: (v - lo) / (hi - lo) if hi != lo else 0.0  # noqa: E731
            if channels:
                out = tuple(ramp_lookup(table, rel(c[i]), interpolate, extrapolate)[i]
                            for i in range(3)) + (1.0,)
            else:
                out = tuple(ramp_lookup(table, rel(c[0]), interpolate, extrapolate))
            return const_float(out[0]) if kind == "float" else const_color(out)
        return self.emit(kind, "ramp", self.reg(src), np.ascontiguousarray(table, np.float32),
                         bool(interpolate), bool(extrapolate), float(lo), float(hi),
                         bool(channels))

    def color_ramp(self, node, out, ctx):
        """Cycles bakes the ramp (any interpolation and colour mode) into a 256-entry table."""
        fac = self.input(node, "Fac", ctx, "float")
        ramp = node.color_ramp
        table = np.array([tuple(ramp.evaluate(i / (RAMP_TABLE_SIZE - 1)))
                          for i in range(RAMP_TABLE_SIZE)], np.float64)
        interpolate = ramp.interpolation != 'CONSTANT'
        if out.identifier == "Alpha":
            return self.ramp(fac, np.repeat(table[:, 3:4], 4, axis=1), interpolate, kind="float")
        return self.ramp(fac, table, interpolate)

    def rgb_curves(self, node, out, ctx):
        """Cycles' curvemapping_color_to_array: the combined curve then each channel's, over
        the range of all curves' points, 256 entries."""
        fac = self.input(node, "Fac", ctx, "float")
        color = self.input(node, "Color", ctx, "color")
        mapping = node.mapping
        mapping.initialize()
        curves = list(mapping.curves)
        los = [c.points[0].location[0] for c in curves[:4] if len(c.points)]
        his = [c.points[-1].location[0] for c in curves[:4] if len(c.points)]
        lo, hi = (min(los), max(his)) if los else (0.0, 1.0)
        table = np.ones((RAMP_TABLE_SIZE, 4))
        for i in range(RAMP_TABLE_SIZE):
            t = lo + i / (RAMP_TABLE_SIZE - 1) * (hi - lo)
            combined = mapping.evaluate(curves[3], t)
            table[i, :3] = [mapping.evaluate(curves[c], combined) for c in range(3)]
        curved = self.ramp(color, table, True, mapping.extend == 'EXTRAPOLATED', lo, hi,
                           channels=True)
        if fac.is_const and 0.0 <= fac.const[0] <= 1.0:
            return self.mix("MIX", fac, color, curved)
        # Cycles does not clamp this factor: color + fac * (curved - color).
        delta = self.vector_op("SUBTRACT", curved, color)
        return self.as_color(self.vector_op("MULTIPLY_ADD", delta, fac, color))

    def vector_op(self, op, a, b, c=None):
        """Vector Math on values (floats broadcast), folded when constant."""
        a, b = self.as_vector(a), self.as_vector(b)
        c = const_vector((0, 0, 0)) if c is None else self.as_vector(c)
        if a.is_const and b.is_const and c.is_const:
            return const_vector(_vector_math(op, a.const[:3], b.const[:3], c.const[:3], 1.0))
        return self.emit("vector", "vector_math", self.reg(a), self.reg(b), self.reg(c), self.reg(ONE),
                         op)

    def color_space(self, v, conversion, kind):
        if v.is_const:
            c = _COLOR_SPACES[conversion](v.const[:3])
            return Val(kind, tuple(c) + (v.const[3],))
        return self.emit(kind, "color_space", self.reg(v), conversion)

    def separate(self, v, axis):
        if v.is_const:
            return const_float(v.const[axis])
        return self.emit("float", "separate", self.reg(v), axis)

    def combine(self, a, b, c, kind):
        if a.is_const and b.is_const and c.is_const:
            xyz = (a.const[0], b.const[0], c.const[0])
            return const_color(xyz + (1.0,)) if kind == "color" else const_vector(xyz)
        return self.emit(kind, "combine", self.reg(a), self.reg(b), self.reg(c), kind == "color")

    def separate_color(self, node, out, ctx):
        color = self.input(node, "Color" if "Color" in node.inputs else "Image", ctx, "color")
        mode = getattr(node, "mode", 'HSV' if node.type == 'SEPHSV' else 'RGB')
        if mode in ('HSV', 'HSL'):
            color = self.color_space(color, f"RGB_TO_{mode}", "color")
        axis = [o.identifier for o in node.outputs].index(out.identifier)
        return self.separate(color, axis)

    def combine_color(self, node, out, ctx):
        ins = [self.value(s, ctx, "float") for s in list(node.inputs)[:3]]
        mode = getattr(node, "mode", 'HSV' if node.type == 'COMBHSV' else 'RGB')
        color = self.combine(*ins, "color")
        if mode in ('HSV', 'HSL'):
            color = self.color_space(color, f"{mode}_TO_RGB", "color")
        return color

    def separate_xyz(self, node, out, ctx):
        socket = node.inputs["Vector"]
        v = self.value(socket, ctx, "vector") or self.socket_default(socket, "vector")
        return self.separate(v, "XYZ".index(out.identifier))

    def combine_xyz(self, node, out, ctx):
        return self.combine(*(self.input(node, k, ctx, "float") for k in "XYZ"), "vector")

    def hue_saturation(self, node, out, ctx):
        ins = [self.input(node, "Color", ctx, "color")] + [
            self.input(node, k, ctx, "float") for k in ("Hue", "Saturation", "Value", "Fac")]
        if all(v.is_const for v in ins):
            c = _hsv_node(ins[0].const[:3], *(v.const[0] for v in ins[1:]))
            return const_color(tuple(c) + (1.0,))
        return self.emit("color", "hsv", *(self.reg(v) for v in ins))

    def gamma(self, node, out, ctx):
        c = self.input(node, "Color", ctx, "color")
        g = self.input(node, "Gamma", ctx, "float")
        if c.is_const and g.is_const:
            return const_color(tuple(_gamma(c.const[:3], g.const[0])) + (1.0,))
        return self.emit("color", "gamma", self.reg(c), self.reg(g))

    def bright_contrast(self, node, out, ctx):
        c = self.input(node, "Color", ctx, "color")
        bright = self.input(node, "Bright", ctx, "float")
        contrast = self.input(node, "Contrast", ctx, "float")
        if c.is_const and bright.is_const and contrast.is_const:
            a, b = 1.0 + contrast.const[0], bright.const[0] - contrast.const[0] * 0.5
            return const_color(tuple(max(a * x + b, 0.0) for x in c.const[:3]) + (1.0,))
        return self.emit("color", "bright_contrast", self.reg(c), self.reg(bright),
                         self.reg(contrast))

    def clamp_node(self, node, out, ctx):
        v, lo, hi = (self.input(node, k, ctx, "float") for k in ("Value", "Min", "Max"))
        if v.is_const and lo.is_const and hi.is_const:
            return const_float(_clamp(v.const[0], lo.const[0], hi.const[0], node.clamp_type))
        return self.emit("float", "clamp", self.reg(v), self.reg(lo), self.reg(hi),
                         node.clamp_type)

    def map_range(self, node, out, ctx):
        by_id = {s.identifier: s for s in node.inputs}
        mode = node.interpolation_type
        if node.data_type == 'FLOAT_VECTOR':
            if out.identifier != "Vector":
                return ZERO
            ins = [self.value(by_id[k], ctx, "vector") or self.socket_default(by_id[k], "vector")
                   for k in ("Vector", "From_Min_FLOAT3", "From_Max_FLOAT3", "To_Min_FLOAT3",
                             "To_Max_FLOAT3", "Steps_FLOAT3")]
            if all(v.is_const for v in ins):
                return const_vector(_map_range_vector(*(v.const[:3] for v in ins), mode,
                                                      node.clamp))
            return self.emit("vector", "map_range_vector", *(self.reg(v) for v in ins), mode,
                             bool(node.clamp))
        if node.data_type != 'FLOAT':
            return NotImplemented
        ins = [self.value(by_id[k], ctx, "float")
               for k in ("Value", "From Min", "From Max", "To Min", "To Max", "Steps")]
        mode = node.interpolation_type
        if all(v.is_const for v in ins):
            return const_float(_map_range(*(v.const[0] for v in ins), mode, node.clamp))
        return self.emit("float", "map_range", *(self.reg(v) for v in ins), mode,
                         bool(node.clamp))

    def vector_math(self, node, out, ctx):
        op = node.operation
        if op not in VECTOR_MATH_OPS:
            return NotImplemented
        by_id = {s.identifier: s for s in node.inputs}
        a, b, c = (self.value(by_id[k], ctx, "vector") or self.socket_default(by_id[k], "vector")
                   for k in ("Vector", "Vector_001", "Vector_002"))
        scale = self.value(by_id["Scale"], ctx, "float")
        value_op = op in VECTOR_MATH_VALUE_OPS
        if (out.identifier == "Value") != value_op:  # the output this operation leaves at 0
            return ZERO if out.identifier == "Value" else const_vector((0, 0, 0))
        kind = "float" if value_op else "vector"
        if all(v.is_const for v in (a, b, c, scale)):
            r = _vector_math(op, a.const[:3], b.const[:3], c.const[:3], scale.const[0])
            return const_float(r) if value_op else const_vector(r)
        return self.emit(kind, "vector_math", self.reg(a), self.reg(b), self.reg(c),
                         self.reg(scale), op)

    # -------------------------------------------------- procedural textures (issue 21)

    def texture_vector(self, node, ctx):
        """A texture node's Vector: the linked value, or (unlinked) Generated coordinates, as
        Cycles links them in (its ops follow the Bump node's offsets)."""
        tm = node.texture_mapping  # the sidebar's Texture Mapping panel, rarely changed
        if (any(tm.translation) or any(tm.rotation) or tuple(tm.scale) != (1.0, 1.0, 1.0)
                or tm.use_min or tm.use_max or tm.mapping != 'FLAT'
                or (tm.mapping_x, tm.mapping_y, tm.mapping_z) != ('X', 'Y', 'Z')):
            self.problem(f"'{node.name}': its Texture Mapping settings are not supported "
                         "(ignored; a Mapping node works)")
        socket = next(s for s in node.inputs if s.identifier == "Vector")
        vec = self.value(socket, ctx, "vector")
        return self.object_coords("generated") if vec is None else vec

    def _texture_floats(self, node, names, ctx):
        """Registers of float inputs, found by identifier: inputs[name] skips the sockets
        that the node's mode makes unavailable (W of 3D noise), which still read as their
        values (the core ignores what the mode does not use)."""
        by_id = {s.identifier: s for s in node.inputs}
        return [self.reg(self.value(by_id[name], ctx, "float")) for name in names]

    def noise_texture(self, node, out, ctx):
        """Cycles' Noise Texture (always emitted: the core evaluates a non-varying program once)."""
        dims = int(node.noise_dimensions[0])
        vec = None if dims == 1 else self.reg(self.texture_vector(node, ctx))  # 1D reads only W
        floats = self._texture_floats(node, ("W", "Scale", "Detail", "Roughness", "Lacunarity",
                                             "Offset", "Gain", "Distortion"), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_noise", vec, *floats, dims,
                         node.noise_type, bool(node.normalize), color)

    def wave_texture(self, node, out, ctx):
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Distortion", "Detail", "Detail Scale",
                                             "Detail Roughness", "Phase Offset"), ctx)
        direction = node.bands_direction if node.wave_type == 'BANDS' else node.rings_direction
        kind = "color" if out.identifier == "Color" else "float"  # Color is (Fac, Fac, Fac)
        return self.emit(kind, "tex_wave", vec, *floats, node.wave_type, direction,
                         node.wave_profile)

    def magic_texture(self, node, out, ctx):
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Distortion"), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_magic", vec, *floats,
                         int(node.turbulence_depth), color)

    def white_noise_texture(self, node, out, ctx):
        dims = int(node.noise_dimensions[0])
        vec = None
        if dims != 1:
            v = self.value(next(s for s in node.inputs if s.identifier == "Vector"), ctx,
                           "vector")
            # Cycles gives this node no implicit coordinates: unlinked, its Vector is (0, 0, 0).
            vec = self.reg(v if v is not None else const_vector((0, 0, 0)))
        (w,) = self._texture_floats(node, ("W",), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_white_noise", vec, w, dims, color)

    # -------------------------------------------------- vector and colour nodes (issue 21)

    def _vector_or_zero(self, node, identifier, ctx):
        """A vector input found by identifier (also when the node's mode hides it); an
        unlinked hidden-value one reads (0, 0, 0), as Cycles gives these nodes no implicit
        coordinates."""
        socket = next(s for s in node.inputs if s.identifier == identifier)
        v = self.value(socket, ctx, "vector")
        return v if v is not None else const_vector((0, 0, 0))

    def vector_rotate(self, node, out, ctx):
        """Vector Rotate, every type, Invert, every input linkable (always emitted: the core
        evaluates a program that reads no shading point once)."""
        regs = [self.reg(self._vector_or_zero(node, name, ctx)) for name in ("Vector", "Center", "Axis")]
        regs += self._texture_floats(node, ("Angle",), ctx)
        regs.append(self.reg(self._vector_or_zero(node, "Rotation", ctx)))
        return self.emit("vector", "vector_rotate", *regs, node.rotation_type, bool(node.invert))

    def vector_transform(self, node, out, ctx):
        """Vector Transform between world, object and camera space (points, vectors, normals)."""
        v = self.reg(self._vector_or_zero(node, "Vector", ctx))
        return self.emit("vector", "vector_transform", v, node.vector_type, node.convert_from,
                         node.convert_to)

    def blackbody(self, node, out, ctx):
        (t,) = self._texture_floats(node, ("Temperature",), ctx)
        return self.emit("color", "blackbody", t)

    def wavelength(self, node, out, ctx):
        (w,) = self._texture_floats(node, ("Wavelength",), ctx)
        return self.emit("color", "wavelength", w)

    def tangent_node(self, node, out, ctx):
        """Tangent: radial around an object axis (from the generated coordinates) or a UV
        map's tangent (per triangle from its uvs, where Cycles interpolates MikkTSpace's)."""
        if node.direction_type == 'UV_MAP':
            k = self.uv(node.uv_map, f"'{node.name}'")
            return self.emit("vector", "tangent", "UV_MAP", k)
        return self.emit("vector", "tangent", node.axis, 0)

    def gabor_texture(self, node, out, ctx):
        """Cycles' Gabor Texture, 2D and 3D, every output."""
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Frequency", "Anisotropy", "Orientation 2D"),
                                      ctx)
        o3 = self.reg(self._vector_or_zero(node, "Orientation 3D", ctx))
        which = {"Phase": "PHASE", "Intensity": "INTENSITY"}.get(out.identifier, "VALUE")
        return self.emit("float", "tex_gabor", vec, *floats, o3, node.gabor_type, which)

    def ambient_occlusion(self, node, out, ctx):
        """Ambient Occlusion: rays traced from the shading point as Cycles' (Samples,
        Distance, Inside, Only Local); Color is AO times the Color input."""
        color = self.reg(self.input(node, "Color", ctx, "color"))
        (dist,) = self._texture_floats(node, ("Distance",), ctx)
        normal = self.normal(node, ctx)
        which = "AO" if out.identifier == "AO" else "COLOR"
        return self.emit("float" if which == "AO" else "color", "ambient_occlusion", color, dist,
                         None if normal is None else self.reg(normal), int(node.samples),
                         bool(node.inside), bool(node.only_local), which)

    def bevel(self, node, out, ctx):
        """Bevel: the instance's smooth normals within Radius, found by traced rays as Cycles'
        (Samples); a linked Normal keeps its own bend."""
        (radius,) = self._texture_floats(node, ("Radius",), ctx)
        normal = self.normal(node, ctx)
        return self.emit("vector", "bevel", radius, None if normal is None else self.reg(normal),
                         int(node.samples))

    def wireframe(self, node, out, ctx):
        """Wireframe: 1 near the triangles' edges (Size in world units, or in pixels)."""
        (size,) = self._texture_floats(node, ("Size",), ctx)
        extra = (self.bump_state,) if self.bump_state else ()
        return self.emit("float", "wireframe", size, bool(node.use_pixel_size), *extra)

    def camera_coords(self, which):
        """Texture Coordinate's Camera or Window (at the current bump offset)."""
        key = ("camera_coords", which, self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", "camera_coords", which, *extra)
        return self.cache[key]

    _VALUE_NODES = {
        'FRESNEL': fresnel_node, 'LAYER_WEIGHT': layer_weight, 'BUMP': bump,
        'LIGHT_PATH': light_path, 'OBJECT_INFO': object_info, 'HAIR_INFO': curves_info,
        'VALTORGB': color_ramp,
        'CURVE_RGB': rgb_curves, 'VERTEX_COLOR': color_attribute, 'ATTRIBUTE': attribute_node,
        'SEPARATE_COLOR': separate_color, 'SEPRGB': separate_color, 'SEPHSV': separate_color,
        'COMBINE_COLOR': combine_color, 'COMBRGB': combine_color, 'COMBHSV': combine_color,
        'SEPXYZ': separate_xyz, 'COMBXYZ': combine_xyz, 'HUE_SAT': hue_saturation,
        'GAMMA': gamma, 'BRIGHTCONTRAST': bright_contrast, 'CLAMP': clamp_node,
        'MAP_RANGE': map_range, 'VECT_MATH': vector_math,
        'TEX_NOISE': noise_texture, 'TEX_WAVE': wave_texture, 'TEX_MAGIC': magic_texture,
        'TEX_WHITE_NOISE': white_noise_texture,
        **tex_patterns.NODES,
        'VECTOR_ROTATE': vector_rotate, 'VECT_TRANSFORM': vector_transform,
        'BLACKBODY': blackbody, 'WAVELENGTH': wavelength, 'TANGENT': tangent_node,
        'TEX_GABOR': gabor_texture, 'AMBIENT_OCCLUSION': ambient_occlusion,
        'BEVEL': bevel, 'WIREFRAME': wireframe,
    }

    def tex_coord(self, node, oid):
        if oid == "UV":
            if node.from_instancer:
                self.problem(f"'{node.name}': UV from instancer is not supported")
            return self.uv_value("", f"'{node.name}'")
        if oid in ("Object", "Generated"):
            if oid == "Object" and node.object is not None:
                self.problem(f"'{node.name}': Object coordinates of another object "
                             f"('{node.object.name}') are not supported (its own object's)")
            return self.object_coords(oid.lower())
        if oid == "Normal":
            return self.emit("vector", "object_normal")
        if oid == "Reflection":
            return self.emit("vector", "geometry", "REFLECTION")
        if oid in ("Camera", "Window"):
            return self.camera_coords(oid.upper())
        self.problem(f"'{node.name}': {oid} coordinates are not supported (0)")
        return const_vector((0, 0, 0))

    def image_texture(self, node, out, ctx):
        what = f"'{node.name}'"
        image = node.image
        loaded = self.images.load(image, self.problems) if image is not None else None
        if image is None:
            self.problem(f"{what} has no image (magenta)")
        if loaded is None:
            if out.identifier == "Alpha":
                return ONE
            return const_color(MISSING_TEXTURE)
        if out.identifier == "Alpha" and not loaded.has_alpha:
            return ONE
        vec = self.value(node.inputs["Vector"], ctx, "vector")
        if vec is None:
            vec = self.uv_value("", what)
        if node.projection != 'FLAT':
            self.problem(f"{what}: {node.projection.lower()} projection is not supported "
                         "(flat)")
        interp = {"Closest": "CLOSEST"}.get(node.interpolation, "LINEAR")
        if node.interpolation in ("Cubic", "Smart"):
            self.problem(f"{what}: {node.interpolation} interpolation is approximated by Linear")
        ext = node.extension
        if ext == 'MIRROR':
            self.problem(f"{what}: Mirror extension is not supported (Repeat)")
            ext = 'REPEAT'
        if ext not in ('REPEAT', 'EXTEND', 'CLIP'):
            ext = 'REPEAT'
        if out.identifier == "Alpha":
            index = self.images.index(image, loaded, "alpha")
            return self.emit("float", "image", self.reg(vec), index, interp, ext)
        # As Cycles: with the Alpha output in use, Color is divided by the filtered alpha.
        alpha_out = node.outputs.get("Alpha")
        unassociate = (alpha_out is not None and alpha_out.is_linked and loaded.has_alpha
                       and loaded.unassociate)
        index = self.images.index(image, loaded, "color")
        if unassociate:
            return self.emit("color", "image", self.reg(vec), index, interp, ext, True)
        return self.emit("color", "image", self.reg(vec), index, interp, ext)

    def mapping(self, node, ctx):
        vec = self.input(node, "Vector", ctx, "vector")
        vtype = node.vector_type
        params = {}
        for name, default in (("Location", (0, 0, 0)), ("Rotation", (0, 0, 0)),
                              ("Scale", (1, 1, 1))):
            socket = node.inputs.get(name)
            if socket is None or not socket.enabled:
                params[name] = default
            else:
                params[name] = self.const_input(node, name, ctx, "vector").const[:3]
        m = mapping_matrix(vtype, params["Location"], params["Rotation"], params["Scale"])
        if vec.is_const:
            v = m[:, :3].astype(np.float64) @ np.array(vec.const[:3]) + m[:, 3]
            return const_vector(v)
        return self.emit("vector", "mapping", self.reg(vec), m)

    def mix_color(self, node, blend, fac, a, b, clamp):
        if blend not in MIX_BLENDS:
            self.problem(f"'{node.name}': blend mode {blend.replace('_', ' ').title()} is not "
                         "supported (Mix)")
            blend = "MIX"
        return self.mix(blend, fac, a, b, clamp)

    def mix_node(self, node, oid, ctx):
        """Blender's Mix node; its sockets share names, so they are found by identifier."""
        by_id = {s.identifier: s for s in node.inputs}
        dtype = node.data_type
        if dtype == 'RGBA':
            fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            return self.mix_color(node, node.blend_type, fac,
                                  self.value(by_id["A_Color"], ctx, "color"),
                                  self.value(by_id["B_Color"], ctx, "color"),
                                  node.clamp_result)
        if dtype == 'FLOAT':
            fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            return self.mix("MIX", fac, self.value(by_id["A_Float"], ctx, "float"),
                            self.value(by_id["B_Float"], ctx, "float"), kind="float")
        if dtype == 'VECTOR':
            if node.factor_mode == 'NON_UNIFORM':
                self.problem(f"'{node.name}': non-uniform factor is not supported (its X is "
                             "used)")
                fac = self.value(by_id["Factor_Vector"], ctx, "vector")
                fac = const_float(fac.const[0]) if fac.is_const else Val("float", reg=fac.reg)
            else:
                fac = self.value(by_id["Factor_Float"], ctx, "float")
            self._note_unclamped_factor(node, fac)
            a = self.value(by_id["A_Vector"], ctx, "vector")
            b = self.value(by_id["B_Vector"], ctx, "vector")
            return self.mix("MIX", fac, a, b, kind="vector")
        return NotImplemented

    def _note_unclamped_factor(self, node, fac):
        if not node.clamp_factor and not (fac.is_const and 0.0 <= fac.const[0] <= 1.0):
            self.problem(f"'{node.name}': an unclamped factor is clamped to [0, 1]")

    def math_node(self, node, ctx):
        op = node.operation
        a = self.value(node.inputs[0], ctx, "float")
        b = self.value(node.inputs[1], ctx, "float")
        clamp = node.use_clamp
        if op in MATH_OPS:
            c = self.value(node.inputs[2], ctx, "float") if op in MATH_OPS_3 else None
            return self.math(op, a, b, clamp, c)
        self.problem(f"'{node.name}': math operation {op.replace('_', ' ').title()} is not "
                     "supported (its first value is used)")
        return self.math("ADD", a, ZERO, clamp)

    def normal_map(self, node, ctx):
        what = f"'{node.name}'"
        if node.space != 'TANGENT':
            self.problem(f"{what}: {node.space.replace('_', ' ').lower()} space normal maps "
                         "are not supported (ignored)")
            return None
        color = self.input(node, "Color", ctx, "color")
        strength = self.input(node, "Strength", ctx, "float")
        if strength.is_const and strength.const[0] == 0.0:
            return None
        k = self.uv(node.uv_map, what)
        return self.emit("vector", "normal_map", self.reg(color), self.reg(strength), k)

    # -------------------------------------------------- shaders

    def closure(self, kind, weight, **params):
        if self.is_zero(weight):
            return
        regs = {k: self.reg(v) for k, v in params.items() if v is not None}
        if weight is not None and weight.is_const and all(x == 1.0 for x in weight.const[:3]):
            weight = None
        w = None if weight is None else self.reg(self.as_color(weight))
        self.ops.append(("closure", kind, w, regs))

    def principled_hair(self, node, inp, weight):
        """The Principled Hair BSDF as Cycles' Chiang model (core: HairChiangBsdf); Huang's
        model falls back to it with a warning."""
        if node.model != 'CHIANG':
            self.problem(f"'{node.name}': the Huang hair model is not supported (rendered with "
                         "Chiang's)")
        mode = {'ABSORPTION': "absorption", 'MELANIN': "melanin"}.get(node.parametrization, "color")
        params = dict(roughness=inp("Roughness", "float"),
                      radial_roughness=inp("Radial Roughness", "float"), coat=inp("Coat", "float"),
                      ior=inp("IOR", "float"), offset=inp("Offset", "float"),
                      random_roughness=inp("Random Roughness", "float"))
        if mode == "absorption":
            params["absorption"] = inp("Absorption Coefficient", "vector")
        elif mode == "melanin":
            params.update(melanin=inp("Melanin", "float"), melanin_redness=inp("Melanin Redness", "float"),
                          tint=inp("Tint", "color"), random_color=inp("Random Color", "float"))
        else:
            params["color"] = inp("Color", "color")
        if node.inputs["Random"].is_linked:
            params["random"] = inp("Random", "float")
        elif any(v is not None and not (v.is_const and v.const[0] == 0.0)
                 for v in (params.get("random_roughness"), params.get("random_color"))):
            # Unlinked: Cycles reads the strand's own random number (Curves Info's Random).
            params["random"] = self.emit("float", "curves_info", "RANDOM")
        self.closure("principled_hair_" + mode, weight, **params)

    def shader_input(self, socket, ctx, weight):
        """Emits the closures of what feeds shader input `socket`, scaled by weight."""
        if self.is_zero(weight):
            return
        src = self.source(socket, ctx)
        if src is None or src[0] == "default":
            return  # nothing connected: no closure (Cycles renders black)
        _, node, out, nctx = src
        if out.type != 'SHADER':  # Cycles turns a value linked into a shader into emission
            v = self.node_output(node, out, nctx, socket, "color")
            self.closure("emission", weight, color=self.as_color(v) if v is not None else ONE)
            return
        key = (node.as_pointer(), out.identifier, self.ctx_key(nctx))
        if key in self.visiting:
            raise _Cycle(node.name)
        self.visiting.add(key)
        try:
            self.shader_node(node, nctx, weight)
        finally:
            self.visiting.discard(key)

    def normal(self, node, ctx, name="Normal"):
        socket = node.inputs.get(name)
        return None if socket is None else self.value(socket, ctx, "vector")

    def _note_distribution(self, node, roughness, allowed):
        dist = node.distribution
        if dist in allowed:
            return
        if roughness.is_const and roughness.const[0] == 0.0:
            return  # every distribution is the same perfect mirror
        self.problem(f"'{node.name}': {dist.replace('_', ' ').title()} distribution is "
                     "approximated by GGX")

    @staticmethod
    def _multiscatter(node, roughness):
        """ONE (a flag register) for Multiscatter GGX, which the core's energy compensation
        follows; None for single-scatter GGX and for a constant zero roughness (a mirror)."""
        if node.distribution != 'MULTI_GGX':
            return None
        if roughness.is_const and roughness.const[0] == 0.0:
            return None
        return ONE

    def shader_node(self, node, ctx, weight):
        t = node.type
        inp = lambda name, kind: self.input(node, name, ctx, kind)  # noqa: E731
        if t == 'MIX_SHADER':
            fac = self.math("ADD", inp("Fac", "float"), ZERO, clamp=True)
            w2 = self.scale(weight, fac)
            w1 = self.scale(weight, self.math("SUBTRACT", ONE, fac))
            self.shader_input(node.inputs[1], ctx, w1)
            self.shader_input(node.inputs[2], ctx, w2)
        elif t == 'ADD_SHADER':
            self.shader_input(node.inputs[0], ctx, weight)
            self.shader_input(node.inputs[1], ctx, weight)
        elif t == 'BSDF_DIFFUSE':
            # A Roughness that is not a constant zero: Cycles' Oren-Nayar in the core.
            r = inp("Roughness", "float")
            rough = {} if r.is_const and r.const[0] == 0.0 else {"roughness": r}
            self.closure("diffuse", weight, color=inp("Color", "color"),
                         normal=self.normal(node, ctx), **rough)
        elif t == 'BSDF_TOON':
            glossy = {"glossy": ONE} if node.component == 'GLOSSY' else {}
            self.closure("toon", weight, color=inp("Color", "color"), size=inp("Size", "float"),
                         smooth=inp("Smooth", "float"), normal=self.normal(node, ctx), **glossy)
        elif t == 'BSDF_SHEEN':
            # Microfibre (Zeltner et al., Cycles' default) or Ashikhmin velvet.
            velvet = {"velvet": ONE} if getattr(node, "distribution", 'MICROFIBER') == 'ASHIKHMIN' else {}
            self.closure("sheen", weight, color=inp("Color", "color"),
                         roughness=inp("Roughness", "float"), normal=self.normal(node, ctx), **velvet)
        elif t == 'BSDF_GLOSSY':
            rough = inp("Roughness", "float")
            self._note_distribution(node, rough, ('GGX', 'MULTI_GGX'))
            self.closure("glossy", weight, color=inp("Color", "color"), roughness=rough,
                         normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough),
                         **self._anisotropy(node, ctx, "Anisotropy", "Rotation"))
        elif t in ('BSDF_GLASS', 'BSDF_REFRACTION'):
            rough = inp("Roughness", "float")
            self._note_distribution(node, rough, ('GGX', 'MULTI_GGX'))
            self.closure("glass" if t == 'BSDF_GLASS' else "refraction", weight,
                         color=inp("Color", "color"), roughness=rough, ior=inp("IOR", "float"),
                         normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough) if t == 'BSDF_GLASS' else None)
        elif t == 'BSDF_METALLIC':
            rough = inp("Roughness", "float")
            self._note_distribution(node, rough, ('GGX', 'MULTI_GGX'))
            physical = node.fresnel_type == 'PHYSICAL_CONDUCTOR'
            params = dict(ior=inp("IOR", "vector"), extinction=inp("Extinction", "vector"),
                          physical=ONE) if physical else dict(
                base_color=inp("Base Color", "color"), edge_tint=inp("Edge Tint", "color"))
            self.closure("metallic", weight, roughness=rough, normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough), **params,
                         **self._anisotropy(node, ctx, "Anisotropy", "Rotation"))
        elif t == 'BSDF_TRANSLUCENT':
            self.closure("translucent", weight, color=inp("Color", "color"),
                         normal=self.normal(node, ctx))
        elif t == 'BSDF_TRANSPARENT':
            self.closure("transparent", weight, color=inp("Color", "color"))
        elif t == 'BSDF_HAIR_PRINCIPLED':
            self.principled_hair(node, inp, weight)
        elif t == 'EMISSION':
            color = self.scale(inp("Color", "color"), inp("Strength", "float"))
            self.closure("emission", weight, color=self.as_color(color))
        elif t == 'BSDF_PRINCIPLED':
            self.principled(node, ctx, weight)
        elif t == 'HOLDOUT':
            self.closure("holdout", weight)
        elif t == 'SUBSURFACE_SCATTERING':
            # Inputs the method hides (Roughness but for Random Walk, IOR for Burley) are not
            # found by name: the core's defaults stand in, unused.
            opt = lambda name, kind: inp(name, kind) if node.inputs.get(name) is not None else None  # noqa: E731
            self.closure("subsurface", weight, color=inp("Color", "color"), scale=inp("Scale", "float"),
                         radius=inp("Radius", "vector"), ior=opt("IOR", "float"),
                         roughness=opt("Roughness", "float"), anisotropy=opt("Anisotropy", "float"),
                         normal=self.normal(node, ctx), method=self._subsurface_method(node, node.falloff))
        else:
            self._fallback_shader(node, ctx, weight)

    def _anisotropy(self, node, ctx, amount, rotation):
        """The closure keys of a Glossy/Metallic node's anisotropy (none where it is a constant
        zero): the amount, the rotation and the tangent (unlinked: Cycles' default)."""
        aniso = self.input(node, amount, ctx, "float")
        if aniso.is_const and aniso.const[0] == 0.0:
            return {}
        return dict(anisotropy=aniso, rotation=self.input(node, rotation, ctx, "float"),
                    tangent=self.principled_tangent(node, ctx, "Tangent"))

    def _fallback_shader(self, node, ctx, weight):
        """An unsupported shader node: a diffuse closure of its Color input if it has one,
        else grey diffuse."""
        color = node.inputs.get("Color")
        if color is not None and color.type == 'RGBA':
            self.problem(f"'{node.name}' ({node.bl_idname}) is not supported (diffuse of its "
                         "Color)")
            c = self.value(color, ctx, "color")
        else:
            self.problem(f"'{node.name}' ({node.bl_idname}) is not supported (grey diffuse)")
            c = const_color(GREY)
        self.closure("diffuse", weight, color=c)

    def principled(self, node, ctx, weight):
        inp = lambda name, kind: self.input(node, name, ctx, kind)  # noqa: E731
        extra = self._principled_extra(node, ctx)
        alpha = self.math("ADD", inp("Alpha", "float"), ZERO, clamp=True)
        opaque = self.scale(weight, alpha)
        if not (alpha.is_const and alpha.const[0] == 1.0):
            self.closure("transparent", self.scale(weight, self.math("SUBTRACT", ONE, alpha)),
                         color=const_color((1, 1, 1, 1)))
        rough = inp("Roughness", "float")
        coat = {}
        coat_weight = inp("Coat Weight", "float")
        if not (coat_weight.is_const and coat_weight.const[0] <= 0.0):
            coat = dict(coat_weight=coat_weight, coat_roughness=inp("Coat Roughness", "float"),
                        coat_ior=inp("Coat IOR", "float"), coat_tint=inp("Coat Tint", "color"),
                        coat_normal=self.normal(node, ctx, "Coat Normal"))
        # Emission: under a sheen or coat the core dims it by them (Cycles adds it after both
        # layers); else a plain Emission closure of the same weight.
        strength = inp("Emission Strength", "float")
        emission = None
        if not (strength.is_const and strength.const[0] == 0.0):
            emission = self.as_color(self.scale(inp("Emission Color", "color"), strength))
            if coat or "sheen_weight" in extra:
                extra["emission"], emission = emission, None
        self.closure("principled", opaque,
                     base_color=inp("Base Color", "color"),
                     metallic=inp("Metallic", "float"),
                     roughness=rough,
                     ior=inp("IOR", "float"),
                     transmission=inp("Transmission Weight", "float"),
                     specular_level=inp("Specular IOR Level", "float"),
                     specular_tint=inp("Specular Tint", "color"),
                     normal=self.normal(node, ctx),
                     multiscatter=self._multiscatter(node, rough),
                     **coat, **extra)
        if emission is not None:
            self.closure("emission", opaque, color=emission)

    # The Principled BSDF's feature groups beyond the base, coat and emission: (the group,
    # its switch input (left out where it is a constant zero), and its operands (the closure's
    # key, the socket, its kind)). The core reads them from a PrincipledExtra op.
    _PRINCIPLED_GROUPS = (
        ("anisotropy", "Anisotropic", (("anisotropic", "Anisotropic", "float"),
                                       ("anisotropic_rotation", "Anisotropic Rotation", "float"),
                                       ("tangent", "Tangent", "tangent"))),
        ("thin film", "Thin Film Thickness", (("thin_film_thickness", "Thin Film Thickness", "float"),
                                              ("thin_film_ior", "Thin Film IOR", "float"))),
        ("sheen", "Sheen Weight", (("sheen_weight", "Sheen Weight", "float"),
                                   ("sheen_roughness", "Sheen Roughness", "float"),
                                   ("sheen_tint", "Sheen Tint", "color"))),
        ("diffuse roughness", "Diffuse Roughness", (("diffuse_roughness", "Diffuse Roughness", "float"),)),
        ("subsurface", "Subsurface Weight", (("subsurface_weight", "Subsurface Weight", "float"),
                                             ("subsurface_radius", "Subsurface Radius", "vector"),
                                             ("subsurface_scale", "Subsurface Scale", "float"),
                                             ("subsurface_ior", "Subsurface IOR", "float"),
                                             ("subsurface_anisotropy", "Subsurface Anisotropy", "float"))),
    )
    # Groups that the core does not render yet: warned about and left out.
    _PRINCIPLED_UNSUPPORTED = {
    }

    def _principled_extra(self, node, ctx):
        """The closure keys of the Principled feature groups in use (switch input not a
        constant zero); an unsupported one in use is warned about instead."""
        extra, ignored = {}, []
        for group, switch, operands in self._PRINCIPLED_GROUPS:
            socket = node.inputs.get(switch)
            if socket is None:
                continue
            v = self.value(socket, ctx, "float")
            if v.is_const and v.const[0] == 0.0:
                continue
            if group in self._PRINCIPLED_UNSUPPORTED:
                ignored.append(group)
                continue
            for key, name, kind in operands:
                if kind == "tangent":
                    extra[key] = self.principled_tangent(node, ctx, name)
                elif node.inputs.get(name) is not None:
                    extra[key] = self.input(node, name, ctx, kind)
        if ignored:
            self.problem(f"'{node.name}': {', '.join(ignored)} not supported (ignored)")
        if "subsurface_weight" in extra:
            extra["subsurface_method"] = self._subsurface_method(node, node.subsurface_method)
        return extra

    # The core's numbers for Blender's subsurface methods (core/scene/shader.h SubsurfaceMethod).
    _SUBSURFACE_METHODS = {'BURLEY': 0.0, 'RANDOM_WALK': 1.0, 'RANDOM_WALK_SKIN': 2.0}

    def _subsurface_method(self, node, method):
        """A constant register of the method (Burley: Cycles' disk sampling; Random Walk; Skin)."""
        return const_float(self._SUBSURFACE_METHODS.get(method, 1.0))

    def principled_tangent(self, node, ctx, name):
        """The Tangent input; unlinked, Cycles' default for a mesh: the Geometry node's
        Tangent, radial around the object's Z axis from the generated coordinates."""
        socket = node.inputs.get(name)
        if socket is None or not socket.is_linked:
            return self.emit("vector", "tangent", "Z", 0)
        return self.input(node, name, ctx, "vector")

    # -------------------------------------------------- volume

    def volume(self, socket, name):
        """The material's Volume: None (no volume), ((r, g, b), density) for a lone Volume
        Absorption (the core's Beer's law, as before volumes), or a dict of the homogeneous
        medium's sigma_a, sigma_s, g and emission (per unit length, Cycles' meanings)."""
        src = self.source(socket, ())
        if src is None or src[0] == "default":
            return None
        _, node, out, ctx = src
        if node.type == 'VOLUME_ABSORPTION':
            color = self.const_input(node, "Color", ctx, "color").const[:3]
            density = self.const_input(node, "Density", ctx, "float").const[0]
            return (tuple(color), density)
        acc = {"sigma_a": np.zeros(3), "sigma_s": np.zeros(3), "emission": np.zeros(3), "gs": np.zeros(3),
               "g": set()}
        self._volume_node(node, ctx, 1.0, acc, set())
        ss = acc["sigma_s"]
        if len(acc["g"]) > 1:
            self.problem(f"volume of '{name}': scatterings of different anisotropies are combined "
                         "into one (their scattering-weighted mean)")
        g = float(acc["gs"].sum() / ss.sum()) if ss.sum() > 0.0 else 0.0
        vol = {k: tuple(float(x) for x in acc[k]) for k in ("sigma_a", "sigma_s", "emission")}
        vol["g"] = g
        if not any(any(v) for v in (vol["sigma_a"], vol["sigma_s"], vol["emission"])):
            return None
        return vol

    def _clean(self, node, what, values):
        """Volume coefficients: NaN, infinite or negative values mean nothing: 0, with a warning."""
        v = np.asarray(values, dtype=np.float64)
        bad = ~np.isfinite(v) | (v < 0.0)
        if bad.any():
            self.problem(f"'{node.name}': {what} is negative or not a number (clamped to 0)")
            v = np.where(bad, 0.0, v)
        return v

    def _volume_node(self, node, ctx, w, acc, visiting):
        """Adds what volume shader `node` (weight w, a constant) puts into the medium."""
        key = (node.as_pointer(), self.ctx_key(ctx))
        if key in visiting:
            raise _Cycle(node.name)
        visiting = visiting | {key}

        def const(name, kind):
            v = self.const_input(node, name, ctx, kind).const
            return v[:3] if kind == "color" else v[0]

        def sub(socket, weight):
            src = self.source(socket, ctx)
            if src is None or src[0] == "default" or weight == 0.0:
                return
            _, n, out, nctx = src
            if out.type != 'SHADER':
                self.problem(f"a value linked into the volume shader input of '{node.name}' (ignored)")
                return
            self._volume_node(n, nctx, weight, acc, visiting)

        t = node.type
        if t == 'ADD_SHADER':
            sub(node.inputs[0], w)
            sub(node.inputs[1], w)
        elif t == 'MIX_SHADER':
            f = min(max(float(const("Fac", "float")), 0.0), 1.0)
            sub(node.inputs[1], w * (1.0 - f))
            sub(node.inputs[2], w * f)
        elif t == 'VOLUME_ABSORPTION':
            c = np.minimum(self._clean(node, "Color", const("Color", "color")), 1.0)
            d = self._clean(node, "Density", [const("Density", "float")])[0]
            acc["sigma_a"] += w * (1.0 - c) * d
        elif t == 'VOLUME_SCATTER':
            phase = getattr(node, "phase", 'HENYEY_GREENSTEIN')
            if phase != 'HENYEY_GREENSTEIN':
                self.problem(f"'{node.name}': the {phase} phase function is not supported "
                             "(Henyey-Greenstein)")
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0]
            g = float(const("Anisotropy", "float")) if "Anisotropy" in node.inputs else 0.0
            self._add_scatter(acc, w * c * d, g)
        elif t == 'PRINCIPLED_VOLUME':
            # Cycles' svm_node_principled_volume: scattering colour * density; extinction adds
            # (1 - colour)(1 - sqrt(absorption colour)) * density.
            c = self._clean(node, "Color", const("Color", "color"))
            d = self._clean(node, "Density", [const("Density", "float")])[0] * w
            g = float(const("Anisotropy", "float"))
            ac = np.sqrt(self._clean(node, "Absorption Color", const("Absorption Color", "color")))
            self._add_scatter(acc, c * d, g)
            acc["sigma_a"] += np.maximum(1.0 - c, 0.0) * np.maximum(1.0 - ac, 0.0) * d
            strength = float(const("Emission Strength", "float"))
            ec = self._clean(node, "Emission Color", const("Emission Color", "color"))
            if np.isfinite(strength) and strength > 0.0:
                acc["emission"] += w * strength * ec
            if float(const("Blackbody Intensity", "float")) != 0.0:
                self.problem(f"'{node.name}': blackbody emission is not supported (ignored)")
        elif t == 'EMISSION':  # an Emission shader in a Volume emits from the whole volume
            c = self._clean(node, "Color", const("Color", "color"))
            strength = self._clean(node, "Strength", [const("Strength", "float")])[0]
            acc["emission"] += w * strength * c
        else:
            self.problem(f"volume '{node.name}' ({node.bl_idname}) is not supported (ignored)")

    def _add_scatter(self, acc, sigma_s, g):
        g = float(g) if np.isfinite(g) else 0.0
        if not np.any(sigma_s > 0.0):
            return
        acc["sigma_s"] += sigma_s
        acc["gs"] += sigma_s * g
        acc["g"].add(round(g, 6))

    # -------------------------------------------------- entry

    def compile(self, output, name):
        """CompiledShader for a material output node."""
        volume = None
        try:
            self.shader_input(output.inputs["Surface"], (), None)
        except _Cycle as e:
            self.problem(f"node cycle through '{e}' (grey diffuse)")
            self._reset()
            self.closure("diffuse", None, color=const_color(GREY))
        try:
            volume = self.volume(output.inputs["Volume"], name)
        except _Cycle as e:
            self.problem(f"node cycle through '{e}' in the volume (ignored)")
        surface = self.source(output.inputs["Surface"], ())
        if volume is not None and (surface is None or surface[0] == "default"):
            # A Volume without a Surface: the boundary lets everything through (as Cycles').
            self.closure("transparent", None, color=const_color((1.0, 1.0, 1.0)))
        disp = output.inputs.get("Displacement")
        if disp is not None and self.link_into(disp) is not None:
            self.problem("displacement is not supported (ignored)")
        program = allocate_registers(eliminate_dead_code(self.ops))
        if program is None:
            self.problem(f"the material needs more than {MAX_REGISTERS} registers (grey "
                         "diffuse)")
            program = [("const", 0, GREY + (1.0,)),
                       ("closure", "diffuse", None, {"color": 0})]
        absorption = volume if isinstance(volume, tuple) else None
        medium = volume if isinstance(volume, dict) else None
        return CompiledShader(program, absorption, medium, dict(self.uv_used), list(self.problems))

    def _reset(self):
        self.ops = []
        self.nreg = 0
        self.const_regs = {}
        self.cache = {}
        self.visiting = set()
        self.uv_used = {}


# How many register operands (after the destination) each value op has; None = none given.
_OPERANDS = {"const": 0, "uv": 0, "position": 0, "normal": 0, "object": 0, "generated": 0,
             "light_path": 0, "object_info": 0, "curves_info": 0, "attribute": 0, "geometry": 0,
             "object_normal": 0, "mapping": 1, "image": 1,
             "rgb_to_bw": 1, "math": 2, "math3": 3, "mix": 3, "normal_map": 2, "fresnel": 2,
             "layer_weight": 2, "bump": 6, "ramp": 1, "separate": 1, "combine": 3,
             "color_space": 1, "hsv": 5, "gamma": 2, "bright_contrast": 3, "clamp": 3,
             "map_range": 6, "map_range_vector": 6, "vector_math": 4,
             "tex_noise": 9, "tex_wave": 7, "tex_magic": 3, "tex_white_noise": 2,
             "vector_rotate": 5, "vector_transform": 1, "blackbody": 1, "wavelength": 1,
             "camera_coords": 0, "tangent": 0, "tex_gabor": 6,
             "ambient_occlusion": 3, "bevel": 2, "wireframe": 1,
             **tex_patterns.OPERANDS}


def _reads(op):
    name = op[0]
    if name == "closure":
        regs = [r for r in op[3].values()]
        return regs + ([op[2]] if op[2] is not None else [])
    return [r for r in op[2:2 + _OPERANDS[name]] if r is not None]


def _rename(op, m):
    name = op[0]
    if name == "closure":
        return ("closure", op[1], None if op[2] is None else m[op[2]],
                {k: m[v] for k, v in op[3].items()})
    n_regs = _OPERANDS[name]
    out = [name, m[op[1]]]
    out += [None if r is None else m[r] for r in op[2:2 + n_regs]]
    out += list(op[2 + n_regs:])
    return tuple(out)


def eliminate_dead_code(ops):
    """Drops value ops whose result no closure needs (e.g. after a folded mix)."""
    live = set()
    kept = []
    for op in reversed(ops):
        if op[0] != "closure" and op[1] not in live:
            continue
        live.update(_reads(op))
        kept.append(op)
    return kept[::-1]


def allocate_registers(ops):
    """Maps virtual registers onto at most MAX_REGISTERS (linear scan over the straight-line
    program: a register is free again after its last read). None if that is not enough."""
    last = {}
    for i, op in enumerate(ops):
        for r in _reads(op):
            last[r] = i
    free = list(range(MAX_REGISTERS - 1, -1, -1))
    mapping = {}
    out = []
    for i, op in enumerate(ops):
        m = dict(mapping)  # reads are all defined before (straight-line code)
        if op[0] != "closure":
            # The destination never shares a register with this op's own operands.
            if not free:
                return None
            m[op[1]] = mapping[op[1]] = free.pop()
        for r in set(_reads(op)):
            if last.get(r) == i:
                free.append(mapping.pop(r))
        if op[0] != "closure" and op[1] not in last:  # never read: free at once
            free.append(mapping.pop(op[1]))
        out.append(_rename(op, m))
    return out


def compile_material(mat, images, uv_sets):
    """CompiledShader of a bpy Material with nodes, or None when it has no Cycles output."""
    tree = mat.node_tree
    output = tree.get_output_node('CYCLES')
    if output is None:
        return None
    return ShaderCompiler(images, uv_sets, material_index=mat.pass_index).compile(output, mat.name)
