"""Per-dir covered line sets from gcda trees (measurement only)."""
import json, os, subprocess, sys, pickle, glob, shutil
from concurrent.futures import ThreadPoolExecutor
BUILD = "/tmp/sancov/cov/build/coverage"
SRC = "/tmp/sancov/cov/core/"

def lines_of(prefix):
    """(covered set of (file,line)), (instrumented set), covered branch keys, all branch keys"""
    cov, inst, bcov, ball = set(), set(), set(), set()
    gcdas = glob.glob(prefix + "/**/*.gcda", recursive=True)
    for g in gcdas:
        rel = g[len(prefix):]                       # /tmp/sancov/cov/build/coverage/CMakeFiles/...
        gcno = rel[:-5] + ".gcno"
        d = os.path.dirname(g)
        link = g[:-5] + ".gcno"
        if not os.path.exists(link):
            os.symlink(gcno, link)
        out = subprocess.run(["gcov", "-j", "-t", "-b", "-o", d, g], capture_output=True, text=True, cwd=d)
        tu = os.path.basename(rel)
        for chunk in out.stdout.splitlines():
            if not chunk.strip():
                continue
            data = json.loads(chunk)
            for f in data["files"]:
                name = f["file"]
                if not name.startswith(SRC):
                    continue
                name = name[len(SRC):]
                for ln in f["lines"]:
                    k = (name, ln["line_number"])
                    inst.add(k)
                    if ln["count"] > 0:
                        cov.add(k)
                    for i, b in enumerate(ln.get("branches", [])):
                        bk = (tu, name, ln["line_number"], i)
                        ball.add(bk)
                        if b["count"] > 0:
                            bcov.add(bk)
    return cov, inst, bcov, ball

if __name__ == "__main__":
    root = sys.argv[1]
    dirs = sorted(glob.glob(root + "/cheap/*")) + sorted(glob.glob(root + "/test/*"))
    res = {}
    with ThreadPoolExecutor(int(sys.argv[2]) if len(sys.argv) > 2 else 2) as ex:
        for d, r in zip(dirs, ex.map(lines_of, dirs)):
            res[os.path.relpath(d, root)] = r
    pickle.dump(res, open(root + "/sets.pkl", "wb"))
    print(len(res), "dirs")
