"""What the benchmark scripts bench_*.py share: their command line (--out, --quick), their
section docs/bench/<name>.md (build.py bench pastes the sections into docs/benchmarks.md), and
the fresh child processes that report one JSON line. Not named bench_*: build.py runs those."""
import argparse
import json
import subprocess
from pathlib import Path


def parse_args(quick_help):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/")
    ap.add_argument("--quick", action="store_true", help=quick_help)
    return ap.parse_args()


def section_dir(args):
    """docs/bench/ (under --out), created: the sections and their plots go there."""
    out = Path(args.out) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_section(out, name, lines):
    text = "\n".join(lines)
    (out / f"{name}.md").write_text(text)
    print(text)


def proc_status(key):
    """A field of /proc/self/status in bytes (VmHWM: the peak resident size), 0 where absent."""
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    return 0


def run_child(cmd, what, timeout):
    """Runs cmd and returns the JSON of its `RESULT {...}` line; RuntimeError with its output if none."""
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(f"{what} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
