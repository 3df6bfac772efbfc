"""Coverage attribution plugin (measurement only, not part of the project).
Before each test: flush counters gathered so far (cheap tests, collection) into
cov/cheap/<file>; reset. After a test whose protocol took > THRESH s: flush into
cov/test/<n> (nodeid recorded in index), reset."""
import ctypes, glob, os, time, json
import pytest

ROOT = os.environ.get("PL_COV_OUT", "/tmp/sancov/covdata")
THRESH = float(os.environ.get("PL_COV_THRESH", "0.4"))
_lib = None
_current_file = "collect"

def lib():
    global _lib
    if _lib is None:
        # the same object Python's import loads (dlopen refcounts one path)
        so = glob.glob("/tmp/sancov/cov/addon/pathlight_core*.so")[0]
        _lib = ctypes.CDLL(so)
    return _lib

def dump(prefix):
    os.environ["GCOV_PREFIX"] = prefix
    lib().pl_gcov_dump()
    lib().pl_gcov_reset()

@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    global _current_file
    dump(os.path.join(ROOT, "cheap", _current_file))
    _current_file = item.nodeid.split("::")[0].replace("/", "__")
    t0 = time.perf_counter()
    yield
    dt = time.perf_counter() - t0
    if dt > THRESH:
        wid = os.environ.get("PYTEST_XDIST_WORKER", "w")
        key = f"{wid}_{int(time.time()*1e6)}"
        d = os.path.join(ROOT, "test", key)
        dump(d)
        with open(os.path.join(ROOT, "index.jsonl"), "a") as f:
            f.write(json.dumps({"dir": key, "nodeid": item.nodeid, "dt": dt}) + "\n")

def pytest_sessionfinish(session):
    dump(os.path.join(ROOT, "cheap", _current_file))
