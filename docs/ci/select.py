import json, pickle, re, sys, collections
d = pickle.load(open("/tmp/sancov/covdata/sets_3.0.pkl", "rb"))
base_cov, inst, base_b, ball = d["base"]
cands = d["cands"]
cpu = {}
for l in open("/tmp/sancov/cpu_before.jsonl"):
    e = json.loads(l); cpu[e["nodeid"]] = e
total_cpu = sum(e["cpu"] for e in cpu.values()); total_wall = sum(e["wall"] for e in cpu.values())
print(f"sanitizer step: {len(cpu)} tests, cpu {total_cpu:.0f} s, wall(per-test sum) {total_wall:.0f} s")
full = set(base_cov); fullb = set(base_b)
for nid, (dt, (c, i, bc, ba)) in cands.items():
    full |= c; fullb |= bc
print("full lines", len(full), "of", len(inst), "branches", len(fullb), "of", len(ball))
PROTECT_FILES = ("test_fuzz_core.py",)
HOSTILE = re.compile(r"hostile|fuzz|finite|extreme|robust|malformed|garbage|invalid|nan|bad_|huge|degenerate", re.I)
def func(nid): return nid.split("[")[0]
cost = {nid: cpu[nid]["cpu"] for nid in cands if nid in cpu}
missing = [n for n in cands if n not in cpu]
if missing: print("not in sanitizer run:", missing[:5], len(missing))
droppable = [n for n in cost if not n.split("::")[0].endswith(PROTECT_FILES)]
# every hostile test function keeps its cheapest case
byfunc = collections.defaultdict(list)
for n in cpu:
    byfunc[func(n)].append(n)
keep = set()
for f, ns in byfunc.items():
    if HOSTILE.search(f.split("::")[-1]) or HOSTILE.search(f.split("::")[0].split("/")[-1]):
        dropped_here = [n for n in ns if n in droppable]
        if dropped_here and len(dropped_here) == len(ns):
            keep.add(min(ns, key=lambda n: cpu[n]["cpu"]))
drop = set(n for n in droppable if n not in keep)
def rest_sets(drop):
    r, rb = set(base_cov), set(base_b)
    for nid, (dt, (c, i, bc, ba)) in cands.items():
        if nid not in drop:
            r |= c; rb |= bc
    return r, rb
r, rb = rest_sets(drop)
lost = full - r
print("drop all candidates:", len(drop), f"cpu {sum(cost[n] for n in drop):.0f}", "lost lines", len(lost))
# greedy add back: most lost lines per cpu second
while lost:
    best = max(drop, key=lambda n: len(cands[n][1][0] & lost) / max(cost[n], 0.05))
    gain = cands[best][1][0] & lost
    if not gain: break
    drop.discard(best); keep.add(best); lost -= gain
    print(f"  add back {best} ({cost[best]:.1f} cpu s): +{len(gain)} lines")
r, rb = rest_sets(drop)
print("final: dropped", len(drop), f"cpu {sum(cost[n] for n in drop):.0f} of {total_cpu:.0f}",
      f"wall {sum(cpu[n]['wall'] for n in drop):.0f} of {total_wall:.0f}",
      "lines", len(r), "of", len(full), "branches", len(rb), "of", len(fullb))
lostb = fullb - rb
print("lost branches", len(lostb), collections.Counter((b[1]) for b in lostb).most_common(10))
json.dump(sorted(drop), open("/tmp/sancov/drop.json", "w"), indent=1)
json.dump(sorted(keep), open("/tmp/sancov/keep.json", "w"), indent=1)
