"""The compiled program's registers: dead-code elimination and the linear-scan allocation
of the compiler's virtual registers onto the core's MAX_REGISTERS."""

from .folding import op_table

MAX_REGISTERS = 64


def _operands(name):
    """How many register operands follow op `name`'s destination (the core's op table)."""
    return op_table()["ops"][name]


def _reads(op):
    name = op[0]
    if name == "closure":
        regs = [r for r in op[3].values()]
        return regs + ([op[2]] if op[2] is not None else [])
    return [r for r in op[2:2 + _operands(name)] if r is not None]


def _rename(op, m):
    name = op[0]
    if name == "closure":
        return ("closure", op[1], None if op[2] is None else m[op[2]],
                {k: m[v] for k, v in op[3].items()})
    n_regs = _operands(name)
    out = [name, m[op[1]]]
    out += [None if r is None else m[r] for r in op[2:2 + n_regs]]
    out += list(op[2 + n_regs:])
    return tuple(out)


def eliminate_dead_code(ops):
    """Drops value ops whose result no closure needs (e.g. after a folded mix)."""
    live = set()
    kept = []
    for op in reversed(ops):
        if op[0] not in ("closure", "set_normal", "aov_output") and op[1] not in live:  # these: their effect
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
