"""Colour spaces of byte images converted to scene linear as OpenColorIO does it for Cycles,
read from Blender's OCIO config (its bundled config.ocio, or $OCIO as Blender reads it): the
chain of a space's transforms to the reference and from there to the scene_linear role, in
numpy. Implemented: Group, ColorSpace, Matrix, Exponent, ExponentWithLinear, Allocation (lg2,
uniform), Range (lower clamp), Builtin (the ACES AP0/AP1 to CIE-XYZ-D65 Bradford matrices), and
File transforms of .spimtx matrices, .spi1d 1D LUTs (either way) and .cube 3D LUTs (forward,
tetrahedral). What a chain holds beyond that raises Unsupported (the caller warns)."""

import os
import re
from functools import lru_cache

import numpy as np


class Unsupported(Exception):
    """A transform of the config that this module does not implement."""


# ---------------------------------------------------------------- reading the config

def config_path():
    env = os.environ.get("OCIO")
    if env and os.path.isfile(env):
        return env
    import bpy
    return os.path.join(bpy.utils.system_resource('DATAFILES'), "colormanagement", "config.ocio")


def _scalar(text):
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] == '"':
        return text[1:-1]
    try:
        return float(text)
    except ValueError:
        return text


def _split_top(text):
    """`text` split at commas outside [] and {} and quotes."""
    parts, depth, quote, cur = [], 0, False, ""
    for ch in text:
        if ch == '"':
            quote = not quote
        elif not quote and ch in "[{":
            depth += 1
        elif not quote and ch in "]}":
            depth -= 1
        if ch == "," and depth == 0 and not quote:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip():
        parts.append(cur)
    return parts


def _flow(text):
    """A YAML flow value: {k: v, ...}, [a, b, ...] or a scalar."""
    text = text.strip()
    if text.startswith("{"):
        out = {}
        for part in _split_top(text[1:-1]):
            key, _, value = part.partition(":")
            out[key.strip()] = _flow(value)
        return out
    if text.startswith("["):
        return [_flow(p) for p in _split_top(text[1:-1])]
    return _scalar(text)


_TAG = re.compile(r"!<(\w+)>\s*(.*)")


def _transform(tag_text, child_lines):
    """A transform dict {'type': ..., params...} of a `!<Type> {...}` value; a GroupTransform
    takes its children from the `- !<...>` lines under it."""
    m = _TAG.match(tag_text.strip())
    if m is None:
        raise ValueError(f"not a transform: {tag_text!r}")
    kind, rest = m.group(1), m.group(2).strip()
    t = _flow(rest) if rest.startswith("{") else {}
    t["type"] = kind
    if kind == "GroupTransform":
        t["children"] = [_transform(line.split("- ", 1)[1], []) for line in child_lines
                         if line.strip().startswith("- !<")]
        if any(line.strip().startswith("- ") and not line.strip().startswith("- !<") for line in child_lines):
            raise ValueError("unexpected group child")
    return t


@lru_cache(maxsize=4)
def load_config(path):
    """{'roles': {...}, 'spaces': {name or alias: space dict}, 'search': [dirs]} of a config."""
    with open(path, encoding="utf-8") as f:
        lines = [ln.rstrip("\n") for ln in f]
    roles, spaces, search = {}, {}, [os.path.dirname(path)]
    section, space = None, None
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.split(" #")[0].rstrip() if not line.lstrip().startswith("#") else ""
        i += 1
        if not stripped.strip():
            continue
        indent = len(line) - len(line.lstrip())
        if indent == 0:
            key, _, value = stripped.partition(":")
            section = key.strip()
            if section == "search_path":
                search = [os.path.join(os.path.dirname(path), p) for p in _scalar(value).split(":")]
            continue
        if section == "roles" and indent == 2:
            key, _, value = stripped.partition(":")
            roles[key.strip()] = _scalar(value)
        elif section == "colorspaces":
            s = stripped.strip()
            if s.startswith("- !<ColorSpace>"):
                space = {}
                continue
            if space is None or indent != 4:
                continue
            key, _, value = s.partition(":")
            key, value = key.strip(), value.strip()
            if key == "name":
                space["name"] = _scalar(value)
                spaces[space["name"]] = space
            elif key == "aliases":
                for alias in _flow(value):
                    spaces.setdefault(str(alias), space)
            elif key == "isdata":
                space["isdata"] = value == "true"
            elif key in ("to_reference", "to_scene_reference", "from_reference", "from_scene_reference"):
                children = []
                while i < len(lines) and (not lines[i].strip() or len(lines[i]) - len(lines[i].lstrip()) > 4):
                    children.append(lines[i])
                    i += 1
                space[key.replace("_scene", "")] = _transform(value, children)
    return {"roles": roles, "spaces": spaces, "search": search}


# ---------------------------------------------------------------- transforms in numpy

def _inverse_dir(t, inverse):
    return inverse != (str(t.get("direction", "forward")) == "inverse")


def _matrix_from_primaries(xy, white):
    """RGB -> XYZ of primaries xy (3 x 2) with white point `white` (Y = 1)."""
    xyz = np.array([[x / y, 1.0, (1 - x - y) / y] for x, y in xy]).T
    w = np.array([white[0] / white[1], 1.0, (1 - white[0] - white[1]) / white[1]])
    return xyz * np.linalg.solve(xyz, w)


def _bradford(src_white, dst_white):
    b = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
    ws = np.array([src_white[0] / src_white[1], 1.0, (1 - sum(src_white)) / src_white[1]])
    wd = np.array([dst_white[0] / dst_white[1], 1.0, (1 - sum(dst_white)) / dst_white[1]])
    return np.linalg.inv(b) @ np.diag((b @ wd) / (b @ ws)) @ b


_ACES_WHITE, _D65 = (0.32168, 0.33767), (0.3127, 0.3290)
_BUILTIN_PRIMARIES = {  # OCIO's built-in styles: RGB -> CIE XYZ D65 (Bradford adaptation)
    "UTILITY - ACES-AP0_to_CIE-XYZ-D65_BFD": ((0.7347, 0.2653), (0.0, 1.0), (0.0001, -0.0770)),
    "UTILITY - ACES-AP1_to_CIE-XYZ-D65_BFD": ((0.713, 0.293), (0.165, 0.830), (0.128, 0.044)),
}


def _file(name, config):
    for d in config["search"]:
        p = os.path.join(d, name)
        if os.path.isfile(p):
            return p
    raise Unsupported(f"LUT file '{name}' not found")


@lru_cache(maxsize=16)
def _read_lut(path):
    with open(path, encoding="utf-8") as f:
        text = f.read()
    if path.endswith(".spimtx"):
        v = np.array(text.split(), np.float64).reshape(3, 4)
        return ("matrix", v[:, :3], v[:, 3] / 65535.0)
    if path.endswith(".spi1d"):
        head, _, body = text.partition("{")
        lo, hi = map(float, re.search(r"From\s+(\S+)\s+(\S+)", head).groups())
        comps = int(re.search(r"Components\s+(\d+)", head).group(1))
        vals = np.array(body.partition("}")[0].split(), np.float64).reshape(-1, comps)
        return ("lut1d", lo, hi, vals)
    if path.endswith(".cube"):
        size, dmin, dmax, rows = None, np.zeros(3), np.ones(3), []
        for line in text.splitlines():
            s = line.strip()
            if not s or s.startswith("#") or s.startswith("TITLE"):
                continue
            if s.startswith("LUT_3D_SIZE"):
                size = int(s.split()[1])
            elif s.startswith("DOMAIN_MIN"):
                dmin = np.array(s.split()[1:], np.float64)
            elif s.startswith("DOMAIN_MAX"):
                dmax = np.array(s.split()[1:], np.float64)
            elif s[0].isalpha():
                raise Unsupported(f"'{os.path.basename(path)}': {s.split()[0]}")
            else:
                rows.append(s.split())
        if size is None:
            raise Unsupported(f"'{os.path.basename(path)}' is not a 3D LUT")
        # red varies fastest: index [b, g, r]
        return ("lut3d", np.array(rows, np.float64).reshape(size, size, size, 3), dmin, dmax)
    raise Unsupported(f"LUT format of '{os.path.basename(path)}'")


def _lut3d_tetrahedral(rgb, lut, dmin, dmax):
    n = lut.shape[0]
    x = np.clip((rgb - dmin) / (dmax - dmin), 0.0, 1.0) * (n - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), n - 2)
    f = x - i0
    r, g, b = i0[:, 0], i0[:, 1], i0[:, 2]

    def at(dr, dg, db):
        return lut[b + db, g + dg, r + dr]
    fr, fg, fb = f[:, :1], f[:, 1:2], f[:, 2:3]
    c000, c111 = at(0, 0, 0), at(1, 1, 1)
    out = np.empty_like(rgb)
    cases = [  # (condition, the two intermediate corners, the weights' order)
        ((fr >= fg) & (fg >= fb), (1, 0, 0), (1, 1, 0), (fr, fg, fb)),
        ((fr >= fb) & (fb > fg), (1, 0, 0), (1, 0, 1), (fr, fb, fg)),
        ((fb > fr) & (fr >= fg), (0, 0, 1), (1, 0, 1), (fb, fr, fg)),
        ((fg > fr) & (fr >= fb), (0, 1, 0), (1, 1, 0), (fg, fr, fb)),
        ((fg >= fb) & (fb > fr), (0, 1, 0), (0, 1, 1), (fg, fb, fr)),
        ((fb > fg) & (fg > fr), (0, 0, 1), (0, 1, 1), (fb, fg, fr)),
    ]
    done = np.zeros(len(rgb), bool)
    for cond, a, bcorner, (w1, w2, w3) in cases:
        m = cond[:, 0] & ~done
        if m.any():
            ca, cb = at(*a)[m], at(*bcorner)[m]
            out[m] = (1 - w1[m]) * c000[m] + (w1[m] - w2[m]) * ca + (w2[m] - w3[m]) * cb + w3[m] * c111[m]
            done |= m
    return out


def _moncurve(x, gamma, offset, inverse):
    """OCIO's ExponentWithLinear (forward: encoded -> linear), per channel."""
    g, o = np.asarray(gamma)[:3], np.asarray(offset)[:3]
    brk = o / (g - 1.0)  # (encoded break point: value and slope continuous)
    slope = brk / (((brk + o) / (1.0 + o)) ** g)
    if not inverse:
        return np.where(x >= brk, ((np.maximum(x, brk) + o) / (1.0 + o)) ** g, x / slope)
    lin_brk = brk / slope
    return np.where(x >= lin_brk, (1.0 + o) * np.maximum(x, lin_brk) ** (1.0 / g) - o, x * slope)


def _vec4(v):
    v = np.atleast_1d(np.asarray(v, np.float64))
    return np.repeat(v, 4) if v.size == 1 else v


def apply(t, rgb, config, inverse=False, depth=0):
    """`rgb` (N, 3) float64 through transform dict `t` (inverse: its inverse)."""
    if depth > 32:
        raise Unsupported("colour space transforms nest too deep")
    kind = t["type"]
    inv = _inverse_dir(t, inverse)
    if kind == "GroupTransform":
        for child in (reversed(t["children"]) if inv else t["children"]):
            rgb = apply(child, rgb, config, inv, depth + 1)
        return rgb
    if kind == "ColorSpaceTransform":
        src, dst = (t["dst"], t["src"]) if inv else (t["src"], t["dst"])
        return convert(rgb, str(src), str(dst), config, depth + 1)
    if kind == "MatrixTransform":
        m = np.array(t.get("matrix", np.eye(4).ravel()), np.float64).reshape(4, 4)[:3, :3]
        off = _vec4(t.get("offset", 0.0))[:3]
        return np.linalg.solve(m, (rgb - off).T).T if inv else rgb @ m.T + off
    if kind == "ExponentTransform":
        if str(t.get("negative_style", "clamp")) != "clamp":
            raise Unsupported("ExponentTransform negative style")
        v = _vec4(t.get("value", 1.0))[:3]
        return np.maximum(rgb, 0.0) ** (1.0 / v if inv else v)
    if kind == "ExponentWithLinearTransform":
        return _moncurve(rgb, _vec4(t.get("gamma", 1.0)), _vec4(t.get("offset", 0.0)), inv)
    if kind == "AllocationTransform":
        alloc = str(t.get("allocation", "uniform"))
        v = [float(x) for x in t.get("vars", [0.0, 1.0])]
        lo, hi = v[0], v[1]
        off = v[2] if len(v) > 2 else 0.0
        if alloc == "uniform":
            return rgb * (hi - lo) + lo if inv else (rgb - lo) / (hi - lo)
        if alloc == "lg2":
            if inv:
                return np.exp2(rgb * (hi - lo) + lo) - off
            return (np.log2(np.maximum(rgb + off, 2.0 ** -126)) - lo) / (hi - lo)
        raise Unsupported(f"AllocationTransform '{alloc}'")
    if kind == "RangeTransform":
        keys = set(t) - {"type", "direction", "style"}
        if keys != {"min_in_value", "min_out_value"} or t["min_in_value"] != t["min_out_value"]:
            raise Unsupported("RangeTransform other than a lower clamp")
        return np.maximum(rgb, float(t["min_in_value"]))
    if kind == "BuiltinTransform":
        style = str(t.get("style", ""))
        if style not in _BUILTIN_PRIMARIES:
            raise Unsupported(f"BuiltinTransform '{style}'")
        m = _bradford(_ACES_WHITE, _D65) @ _matrix_from_primaries(_BUILTIN_PRIMARIES[style], _ACES_WHITE)
        return rgb @ (np.linalg.inv(m) if inv else m).T
    if kind == "FileTransform":
        lut = _read_lut(_file(str(t["src"]), config))
        if lut[0] == "matrix":
            _, m, off = lut
            return np.linalg.solve(m, (rgb - off).T).T if inv else rgb @ m.T + off
        if lut[0] == "lut1d":
            _, lo, hi, vals = lut
            xs = np.linspace(lo, hi, len(vals))
            out = np.empty_like(rgb)
            for c in range(3):
                ys = vals[:, min(c, vals.shape[1] - 1)]
                if inv:
                    if np.any(np.diff(ys) < 0):
                        raise Unsupported(f"inverse of non-monotonic LUT '{t['src']}'")
                    out[:, c] = np.interp(rgb[:, c], ys, xs)
                else:
                    out[:, c] = np.interp(rgb[:, c], xs, ys)
            return out
        if inv:
            raise Unsupported(f"inverse of 3D LUT '{t['src']}'")
        _, table, dmin, dmax = lut
        return _lut3d_tetrahedral(rgb, table, dmin, dmax)
    raise Unsupported(kind)


def _space(config, name):
    s = config["spaces"].get(name)
    if s is None:
        raise Unsupported(f"colour space '{name}' is not in the config")
    return s


def _to_reference(rgb, space, config, depth):
    if "to_reference" in space:
        return apply(space["to_reference"], rgb, config, False, depth)
    if "from_reference" in space:
        return apply(space["from_reference"], rgb, config, True, depth)
    return rgb  # the reference itself


def _from_reference(rgb, space, config, depth):
    if "from_reference" in space:
        return apply(space["from_reference"], rgb, config, False, depth)
    if "to_reference" in space:
        return apply(space["to_reference"], rgb, config, True, depth)
    return rgb


def convert(rgb, src, dst, config, depth=0):
    a, b = _space(config, src), _space(config, dst)
    if a is b:
        return rgb
    return _from_reference(_to_reference(rgb, a, config, depth), b, config, depth)


# ---------------------------------------------------------------- the chain, flattened

_SEPARABLE = {"ExponentTransform", "ExponentWithLinearTransform", "AllocationTransform", "RangeTransform"}


def _flatten(t, config, inverse, depth, out):
    """The primitive transforms (t, inverse) that `t` applies, in order (groups and colour
    space transforms expanded)."""
    if depth > 32:
        raise Unsupported("colour space transforms nest too deep")
    inv = _inverse_dir(t, inverse)
    if t["type"] == "GroupTransform":
        for child in (reversed(t["children"]) if inv else t["children"]):
            _flatten(child, config, inv, depth + 1, out)
    elif t["type"] == "ColorSpaceTransform":
        src, dst = (t["dst"], t["src"]) if inv else (t["src"], t["dst"])
        _flatten_convert(str(src), str(dst), config, depth + 1, out)
    else:
        out.append((t, inverse))
    return out


def _flatten_convert(src, dst, config, depth, out):
    a, b = _space(config, src), _space(config, dst)
    if a is b:
        return out
    for space, to_ref in ((a, True), (b, False)):
        own, other = ("to_reference", "from_reference") if to_ref else ("from_reference", "to_reference")
        if own in space:
            _flatten(space[own], config, False, depth, out)
        elif other in space:
            _flatten(space[other], config, True, depth, out)
    return out


def _linear_part(t, inverse, config):
    """(M, offset) of an affine step as applied (its direction included), or None."""
    kind = t["type"]
    if kind == "MatrixTransform":
        m = np.array(t.get("matrix", np.eye(4).ravel()), np.float64).reshape(4, 4)[:3, :3]
        off = _vec4(t.get("offset", 0.0))[:3]
    elif kind == "BuiltinTransform" and str(t.get("style", "")) in _BUILTIN_PRIMARIES:
        style = str(t["style"])
        m = _bradford(_ACES_WHITE, _D65) @ _matrix_from_primaries(_BUILTIN_PRIMARIES[style], _ACES_WHITE)
        off = np.zeros(3)
    elif kind == "FileTransform" and str(t["src"]).endswith(".spimtx"):
        _, m, off = _read_lut(_file(str(t["src"]), config))
    else:
        return None
    if _inverse_dir(t, inverse):
        mi = np.linalg.inv(m)
        return mi, -mi @ off
    return m, off


def _separable(t, config):
    kind = t["type"]
    return kind in _SEPARABLE or (kind == "FileTransform" and str(t["src"]).endswith(".spi1d"))


_LEVELS = np.arange(256, dtype=np.float32) / np.float32(255.0)


def _run(steps, rgb, config):
    """`rgb` (N, 3) float64 through flattened `steps`. Byte values (k / 255) go through the
    leading per-channel steps as a 256-entry table, and runs of affine steps as one matrix
    (the same results, less work on big images)."""
    i = 0
    if steps and _separable(steps[0][0], config):
        idx = np.rint(rgb * 255.0)
        if np.array_equal(_LEVELS[np.clip(idx, 0, 255).astype(np.intp)], rgb.astype(np.float32)):
            table = np.repeat(_LEVELS.astype(np.float64)[:, None], 3, axis=1)
            while i < len(steps) and _separable(steps[i][0], config):
                table = apply(steps[i][0], table, config, steps[i][1])
                i += 1
            idx = idx.astype(np.intp)
            rgb = np.stack([table[idx[:, c], c] for c in range(3)], axis=1)
    while i < len(steps):
        part = _linear_part(steps[i][0], steps[i][1], config)
        if part is None:
            rgb = apply(steps[i][0], rgb, config, steps[i][1])
            i += 1
            continue
        m, off = part
        i += 1
        while i < len(steps):
            nxt = _linear_part(steps[i][0], steps[i][1], config)
            if nxt is None:
                break
            m, off = nxt[0] @ m, nxt[0] @ off + nxt[1]
            i += 1
        rgb = rgb @ m.T + off
    return rgb


def to_scene_linear(rgb, space_name, path=None):
    """float32 `rgb` (..., 3) in colour space `space_name` of the config, in scene linear.
    Raises Unsupported for what this module does not implement."""
    config = load_config(path or config_path())
    linear = str(config["roles"].get("scene_linear", "Linear Rec.709"))
    steps = _flatten_convert(space_name, linear, config, 0, [])
    flat = np.asarray(rgb, np.float64).reshape(-1, 3)
    for t, inv in steps:  # (fail before any work on what is not implemented)
        if t["type"] == "FileTransform":
            lut = _read_lut(_file(str(t["src"]), config))
            if lut[0] == "lut3d" and _inverse_dir(t, inv):
                raise Unsupported(f"inverse of 3D LUT '{t['src']}'")
            if lut[0] == "lut1d" and _inverse_dir(t, inv) and np.any(np.diff(lut[3], axis=0) < 0):
                raise Unsupported(f"inverse of non-monotonic LUT '{t['src']}'")
        elif t["type"] not in _SEPARABLE | {"MatrixTransform", "BuiltinTransform"}:
            raise Unsupported(t["type"])
        elif t["type"] == "BuiltinTransform" and str(t.get("style", "")) not in _BUILTIN_PRIMARIES:
            raise Unsupported(f"BuiltinTransform '{t.get('style', '')}'")
    out = _run(steps, flat, config)
    return out.reshape(np.shape(rgb)).astype(np.float32)
