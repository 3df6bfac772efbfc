"""The core's value-op schema (core/scene/shader_ops.h, issue 22) through the module: every
OpCode is made by a closure or by a schema entry, every entry's tuples parse (each choice, the
ends of each range, with and without the optional parameters), and a wrong choice, an
out-of-range integer or a wrong argument count is refused with a message that names the op."""
import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

TABLE = pc.shader_op_table()
SCHEMA = {e["name"]: e for e in TABLE["schema"]}
IES = pc.IesProfile(b"IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 2 1 1 2 0 0 0\n1 1 100\n0 90\n0\n100 50\n")
# Parsed by hand in the bindings (see the comment there); their entries hold registers only.
HAND_PARSED = {"normal_map"}


def sample(p):
    """A valid value for parameter `p` (the first name, the low end, ...)."""
    return {
        "choice": lambda: p["names"][0],
        "int": lambda: p["range"][0],
        "bool": lambda: False,
        "float": lambda: 0.5,
        "image": lambda: 0,
        "values": lambda: (0.25, 0.5, 0.75),
        "matrix3x4": lambda: np.eye(3, 4, dtype=np.float32),
        "ramp_table": lambda: np.array([[0, 0, 0, 1], [1, 1, 1, 1]], np.float32),
        "filter_width": lambda: 0.5,
        "ies_profile": lambda: IES,
        "sky": lambda: pc.sky_texture("PREETHAM"),
    }[p["kind"]]()


def op_tuple(name, params=None, dst=1):
    e = SCHEMA[name]
    params = [sample(p) for p in e["params"]] if params is None else params
    return (name, dst) + (0,) * e["registers"] + tuple(params)


def parse(op):
    s = pc.Scene()
    s.add_image(np.ones((2, 2, 4), np.float32), False)
    s.add_shader("t", [("const", 0, (0.5,)), op, ("closure", "emission", None, {"color": 1})])


def test_every_opcode_is_a_closures_or_has_a_value_op():
    codes = {e["code"]: e["closure"] for e in TABLE["opcodes"]}
    assert sorted(codes) == list(range(len(codes)))
    value_codes = {e["code"] for e in SCHEMA.values()}
    for code, closure in codes.items():
        assert closure != (code in value_codes), code
    assert TABLE["ops"] == {n: e["registers"] for n, e in SCHEMA.items()}  # what the add-on reads
    assert {n for n, e in SCHEMA.items() if e["hand_parsed"]} == HAND_PARSED


def test_the_schema_is_well_formed():
    for name, e in SCHEMA.items():
        assert not (e["hand_parsed"] and e["params"]), name
        optional = [p["optional"] for p in e["params"]]
        assert optional == sorted(optional), name  # optional ones only at the end
        for p in e["params"]:
            assert p["what"], name
            if p["kind"] == "choice":
                assert p["names"] and len(set(p["names"])) == len(p["names"]), name
            if p["kind"] == "int":
                assert p["range"][0] <= p["range"][1], name


@pytest.mark.parametrize("name", sorted(set(SCHEMA) - HAND_PARSED))
def test_every_entry_parses(name):
    e = SCHEMA[name]
    base = [sample(p) for p in e["params"]]
    parse(op_tuple(name, base))
    required = sum(not p["optional"] for p in e["params"])
    parse(op_tuple(name, base[:required]))  # optional parameters left off
    for i, p in enumerate(e["params"]):
        values = {"choice": p.get("names", []) + p.get("alt_names", []), "int": p.get("range", ()),
                  "bool": (False, True), "float": (-2.5, 1e6)}.get(p["kind"], ())
        for v in values:
            args = list(base)
            args[i] = v
            if v in p.get("alt_names", []) and v not in p["names"]:
                # a name of the alternative list: valid once the op's sub is nonzero (Wave's rings)
                j = next(k for k, q in enumerate(e["params"]) if q["field"] == "sub" and q["kind"] == "choice")
                args[j] = e["params"][j]["names"][1]
            parse(op_tuple(name, args))


@pytest.mark.parametrize("name", sorted(set(SCHEMA) - HAND_PARSED))
def test_wrong_arguments_are_refused_naming_the_op(name):
    e = SCHEMA[name]
    base = [sample(p) for p in e["params"]]
    required = sum(not p["optional"] for p in e["params"])
    with pytest.raises(ValueError, match=f"shader op '{name}' takes"):
        parse(op_tuple(name, base + [0]))
    if e["registers"] + required > 0:
        with pytest.raises(ValueError, match=f"shader op '{name}' takes"):
            parse(op_tuple(name, base[:required])[:-1])
    for i, p in enumerate(e["params"]):
        args = list(base)
        if p["kind"] == "choice":
            args[i] = "NO_SUCH_NAME"
            with pytest.raises(ValueError) as err:
                parse(op_tuple(name, args))
            msg = str(err.value)
            assert f"shader op '{name}'" in msg and "unknown" in msg and "'NO_SUCH_NAME'" in msg, msg
            assert p["names"][0] in msg, msg  # the names it takes
        if p["kind"] == "int":
            lo, hi = p["range"]
            for v in (lo - 1, hi + 1):
                args[i] = v
                with pytest.raises(ValueError) as err:
                    parse(op_tuple(name, args))
                msg = str(err.value)
                assert f"shader op '{name}'" in msg and f"[{lo}, {hi}]" in msg and p["what"] in msg, msg
        if p["kind"] == "float":
            args[i] = float("nan")
            with pytest.raises(ValueError, match=f"shader op '{name}': .*finite"):
                parse(op_tuple(name, args))
        if p["kind"] in ("ies_profile", "sky"):  # a core object of that class, nothing else
            args[i] = 3
            with pytest.raises(ValueError, match=f"shader op '{name}': .* must be an? "):
                parse(op_tuple(name, args))


def test_unknown_ops_and_bad_registers_are_refused():
    with pytest.raises(ValueError, match="unknown shader op 'no_such_op'"):
        parse(("no_such_op", 1))
    with pytest.raises(ValueError, match="register out of range: 64"):
        parse(op_tuple("math", dst=64))
    with pytest.raises(ValueError, match="needs a destination register"):
        parse(op_tuple("math", dst=None))
    with pytest.raises(ValueError, match="shader op 'image': unknown image id 1"):
        parse(("image", 1, 0, 1, "LINEAR", "REPEAT"))
