"""The compiled program's registers: dead-code elimination and the linear-scan allocation
of the compiler's virtual registers onto the core's MAX_REGISTERS."""

from . import tex_patterns

MAX_REGISTERS = 64


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
