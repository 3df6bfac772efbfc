"""build.py bench's README table: one headline line per benchmark section between the README's
markers, the rest of the README untouched (no core module or Blender needed)."""
import os
import time

import pytest

import build  # noqa: F401 (puts tools/ on sys.path)
from buildsys import bench

SECTION = """## Equal-time error against Cycles (CPU)

Some prose that stays in docs/benchmarks.md.

| Scene | samples/s Pathlight | all budgets pooled | mean ratio |
|---|---|---|---|
| Cornell box | 46 | 2.58x ± 0.15 | 1.0002 |
| HDR-lit scene | 118 | 16.45x ± 0.35 | 1.0000 |

| A second table | not in the README |
|---|---|
| x | y |
"""
SBVH = """## Spatial splits (SBVH)

| Scene | Spatial splits | Speed-up, primary / diffuse |
|---|---|---|
| Sliver room | off (0 nodes) | 1.00x / 1.00x |
| Sliver room | on (558 nodes) | 2.23x / 1.74x |
"""
NEW = """## A benchmark build.py does not know

| Case | Time (s) | Ratio |
|---|---|---|
| small | 0.1 | 1.5x |
| large | 2.0 | 3.0x |
"""
README = "# Title\n\nBefore the table.\n\n<!-- bench-table:begin -->\nan older table\n<!-- bench-table:end -->\n\n## After\n"


@pytest.fixture
def stamped(monkeypatch):
    monkeypatch.setattr(bench, "machine_description", lambda: "Test CPU, 2 cores")
    monkeypatch.setattr(bench, "git_commit", lambda: "0123456789ab")
    monkeypatch.setattr(bench, "log", lambda msg: None)


def write_sections(tmp_path, started):
    d = tmp_path / "bench"
    d.mkdir()
    paths = []
    for name, text in (("equal_time", SECTION), ("sbvh", SBVH), ("zz_new", NEW)):
        p = d / f"{name}.md"
        p.write_text(text)
        paths.append(p)
    old = started - 3600
    os.utime(paths[1], (old, old))  # not rewritten by this run
    return paths


def table_rows(text):
    inside = text.split(bench.README_BENCH_BEGIN)[1].split(bench.README_BENCH_END)[0]
    return [line for line in inside.splitlines() if line.startswith("| ") and not line.startswith("| Benchmark")]


def test_readme_gets_one_headline_line_per_section(tmp_path, stamped):
    started = time.time()
    sections = write_sections(tmp_path, started)
    readme = tmp_path / "README.md"
    readme.write_text(README)
    bench.update_readme_benchmarks(sections, started, [], readme=readme)
    text = readme.read_text()
    head, tail = README.split(bench.README_BENCH_BEGIN)[0], README.split(bench.README_BENCH_END)[1]
    assert text.startswith(head + bench.README_BENCH_BEGIN + "\n") and text.endswith(bench.README_BENCH_END + tail)
    assert "an older table" not in text and "Test CPU, 2 cores" in text and "0123456789ab" in text
    rows = table_rows(text)
    assert len(rows) == 3
    # The known section: its own figure, every row of its first table only.
    assert rows[0].startswith("| Equal-time error against Cycles (CPU) | Cycles' error over Pathlight's")
    assert rows[0].endswith("| Cornell box 2.58x ± 0.15; HDR-lit scene 16.45x ± 0.35 |")
    assert "not in the README" not in text and "Some prose" not in text
    # Spatial splits: only the rows with splits on; stale, so marked as from an earlier run.
    assert rows[1].startswith("| Spatial splits (SBVH) (earlier run) |")
    assert rows[1].endswith("| Sliver room 2.23x / 1.74x |") and "1.00x / 1.00x" not in rows[1]
    # An unknown section: its first and last columns.
    assert rows[2] == "| A benchmark build.py does not know | Ratio | small 1.5x; large 3.0x |"
    # Running again replaces the table, not appends to it.
    bench.update_readme_benchmarks(sections, started, [], readme=readme)
    assert readme.read_text() == text


def test_readme_without_markers_is_left_alone(tmp_path, stamped, monkeypatch):
    warnings = []
    monkeypatch.setattr(bench, "warn", warnings.append)
    readme = tmp_path / "README.md"
    readme.write_text("# No markers\n")
    bench.update_readme_benchmarks(write_sections(tmp_path, time.time()), time.time(), [], readme=readme)
    assert readme.read_text() == "# No markers\n" and len(warnings) == 1


@pytest.mark.parametrize("stem", sorted(bench.README_BENCH_HEADLINES))
def test_headline_matches_the_section_its_script_writes(stem):
    """Each README headline reads columns of the section that is in docs/bench/ now; a bench
    script that renames one would silently fall back to the generic headline."""
    path = bench.BENCH_SECTIONS / f"{stem}.md"
    assert path.exists(), f"{path} is gone: drop or rename its README headline"
    what, figures = bench.bench_headline(stem, path.read_text().splitlines())
    assert what == bench.README_BENCH_HEADLINES[stem][0] and figures


@pytest.mark.parametrize("out", [["--out", "/tmp/trial"], ["--out=/tmp/trial"], []], ids=["out", "out=", "docs"])
def test_bench_with_out_leaves_docs_and_readme_alone(monkeypatch, tmp_path, out):
    """`build.py bench -- --quick --out DIR`: the scripts write under DIR, and docs/benchmarks.md
    and the README are not reassembled (they were, from docs/bench/, before)."""
    from types import SimpleNamespace
    (tmp_path / "bench_x.py").write_text("")
    monkeypatch.setattr(bench, "BENCH_SCRIPTS", tmp_path)
    monkeypatch.setattr(bench, "setup_and_build", lambda args: {})
    monkeypatch.setattr(bench, "runtime_env", lambda args, env: {})
    calls, assembled = [], []
    monkeypatch.setattr(bench.subprocess, "call", lambda cmd, **kw: calls.append(cmd) or 0)
    monkeypatch.setattr(bench, "assemble_benchmarks", lambda *a: assembled.append(a))
    assert bench.cmd_bench(SimpleNamespace(only=None), ["--quick", *out]) == 0
    assert len(calls) == 1 and calls[0][-len(out) - 1:] == ["--quick", *out]
    assert len(assembled) == (0 if out else 1)
