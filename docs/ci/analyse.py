"""Merge the cheap coverage into one tree; per-candidate line sets for the slow tests."""
import json, os, subprocess, sys, pickle, glob, shutil
from concurrent.futures import ThreadPoolExecutor
sys.path.insert(0, "/tmp/sancov")
from covsets import lines_of
ROOT = "/tmp/sancov/covdata"
T = float(sys.argv[1]) if len(sys.argv) > 1 else 0.8
idx = [json.loads(l) for l in open(ROOT + "/index.jsonl")]
cands = [e for e in idx if e["dt"] >= T]
small = [ROOT + "/test/" + e["dir"] for e in idx if e["dt"] < T]
cheap = sorted(glob.glob(ROOT + "/cheap/*"))
print(len(idx), "test dirs;", len(cands), "candidates;", len(small) + len(cheap), "to merge", flush=True)

def merge_all(dirs, out):
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(dirs[0], out, symlinks=True)
    for d in dirs[1:]:
        tmp = out + ".tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        r = subprocess.run(["gcov-tool", "merge", "-o", tmp, out, d], capture_output=True, text=True)
        if r.returncode:
            print("merge failed", d, r.stderr[-300:]); sys.exit(1)
        shutil.rmtree(out); os.rename(tmp, out)

base = ROOT + "/base"
merge_all(cheap + small, base)
# gcov-tool writes only gcda; drop stale links
for l in glob.glob(base + "/**/*.gcno", recursive=True):
    os.unlink(l)
print("merged", flush=True)
dirs = [base] + [ROOT + "/test/" + e["dir"] for e in cands]
res = {}
with ThreadPoolExecutor(4) as ex:
    for d, r in zip(dirs, ex.map(lines_of, dirs)):
        res[d] = r
out = {"base": res[base], "cands": {e["nodeid"]: (e["dt"], res[ROOT + "/test/" + e["dir"]]) for e in cands}}
pickle.dump(out, open(ROOT + f"/sets_{T}.pkl", "wb"))
print("done", flush=True)
