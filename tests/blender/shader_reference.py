"""Python references of the core's value ops (double precision; Blender's / Cycles' safe
variants: a non-finite result is 0): what the core's float evaluation (pathlight_core
fold_constant, which the add-on folds constants with) is checked against, and the shader
compiler tests' interpreter."""

import math

import numpy as np

# The operations each reference implements (checked against the core's table and Blender's
# node enums in test_core_materials.py).
MATH_OPS = {"ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "POWER", "MINIMUM", "MAXIMUM",
            "LESS_THAN", "GREATER_THAN", "ABSOLUTE", "LOGARITHM", "SQRT", "INVERSE_SQRT",
            "EXPONENT", "SIGN", "ROUND", "FLOOR", "CEIL", "TRUNC", "FRACT", "MODULO",
            "FLOORED_MODULO", "SNAP", "PINGPONG", "SINE", "COSINE", "TANGENT", "ARCSINE",
            "ARCCOSINE", "ARCTANGENT", "ARCTAN2", "SINH", "COSH", "TANH", "RADIANS", "DEGREES",
            "MULTIPLY_ADD", "COMPARE", "SMOOTH_MIN", "SMOOTH_MAX", "WRAP"}
MATH_OPS_3 = {"MULTIPLY_ADD", "COMPARE", "SMOOTH_MIN", "SMOOTH_MAX", "WRAP"}  # read a third value
MIX_BLENDS = {"MIX", "MULTIPLY", "ADD", "SUBTRACT", "SCREEN", "DIVIDE", "DIFFERENCE", "DARKEN",
              "LIGHTEN", "OVERLAY"}
VECTOR_MATH_OPS = {"ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "CROSS_PRODUCT",
                   "PROJECT", "REFLECT", "REFRACT", "FACEFORWARD", "DOT_PRODUCT", "DISTANCE",
                   "LENGTH", "SCALE", "NORMALIZE", "ABSOLUTE", "POWER", "SIGN", "MINIMUM",
                   "MAXIMUM", "FLOOR", "CEIL", "FRACTION", "MODULO", "WRAP", "SNAP", "SINE",
                   "COSINE", "TANGENT"}
VECTOR_MATH_VALUE_OPS = {"DOT_PRODUCT", "DISTANCE", "LENGTH"}


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


def ramp_lookup(table, f, interpolate, extrapolate):
    """Cycles' rgb_ramp_lookup (the core's Ramp op)."""
    n = len(table)
    if extrapolate and (f < 0.0 or f > 1.0):
        t0, t1 = (table[0], table[1]) if f < 0.0 else (table[-1], table[-2])
        k = (-f if f < 0.0 else f - 1.0) * (n - 1)
        return [a + (a - b) * k for a, b in zip(t0, t1)]
    f = min(max(f, 0.0), 1.0) * (n - 1) if math.isfinite(f) else 0.0
    i = min(max(int(f), 0), n - 1)
    w = f - i
    if interpolate and w > 0.0 and i + 1 < n:
        return [a + (b - a) * w for a, b in zip(table[i], table[i + 1])]
    return list(table[i])
