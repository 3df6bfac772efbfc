"""The equal-time method that bench_equal_time.py and bench_realistic.py share: a reference from
both engines' high-sample renders (their mutual relative MSE / 4, the floor, is the reference's
own error and is subtracted), renders at each time budget with different seeds, the engines
alternating, their errors averaged per budget and pooled over all budgets; and the plot of error
against time. Not named bench_*: build.py runs those."""
import numpy as np

ENGINES = ("PATHLIGHT", "CYCLES")
MIN_REPEATS = 2                # renders per engine and budget (seeds 1, 2, ...), errors averaged
REPEAT_SECONDS = 8.0           # ... and at least this much rendering per budget


def repeats_for(budget):
    return max(MIN_REPEATS, int(round(REPEAT_SECONDS / budget)))


def rel_mse(img, ref):
    return float(np.mean((img - ref) ** 2 / (ref**2 + 1e-2)))


def above_floor(err, floor):
    """The error against the truth: the MSE against the reference less the reference's own."""
    return max(err - floor, 1e-3 * err)


def time_to(err_curve, times, target):
    """Log-log interpolation of the time at which an error curve reaches `target`."""
    e, t = np.log(np.asarray(err_curve)), np.log(np.asarray(times))
    if target >= err_curve[0]:
        return times[0]
    if target < min(err_curve):  # extrapolate along the 1/t slope of Monte Carlo
        return float(times[-1] * err_curve[-1] / target)
    for i in range(len(times) - 1):
        if err_curve[i + 1] <= target <= err_curve[i]:
            f = (np.log(target) - e[i]) / (e[i + 1] - e[i])
            return float(np.exp(t[i] + f * (t[i + 1] - t[i])))
    return float("nan")


def pooled_ratio(renders, times, floor):
    """Cycles' error over Pathlight's at equal time from every render of every budget, and its
    standard error. Monte Carlo error falls as 1/t, so error x time estimates one number per
    engine (its inverse efficiency) at each budget; each budget's mean counts once (the short
    budgets have more renders, not more weight). The standard error of the ratio comes from the
    renders' spread (delta method: the two engines' relative standard errors in quadrature); the
    glass box's caustics make single renders' errors heavy-tailed, so it is a guide, not a bound."""
    est = {}
    for e, per_budget in renders.items():
        means, variances = [], []
        for t, errs in zip(times, per_budget):
            x = np.array([above_floor(err, floor) * t for err in errs])
            means.append(x.mean())
            variances.append(x.var(ddof=1) / len(x) if len(x) > 1 else x.mean() ** 2)
        mean = float(np.mean(means))
        est[e] = (mean, float(np.sqrt(np.sum(variances))) / len(means) / mean)
    (p, rp), (c, rc) = est["PATHLIGHT"], est["CYCLES"]
    ratio = c / p
    return ratio, ratio * float(np.hypot(rp, rc))


def measure(render, times, repeats, ref_spp, ref_seed, halves=False):
    """One scene's equal-time figures. render(engine, **settings) returns (image, seconds).
    Returns dict(refs, errors, raw, floor, pooled, renders): the references per engine, the mean error
    per budget with the floor subtracted (errors) and without (raw), the floor and the pooled
    ratio with its standard error, and each engine's per-budget errors (renders). halves: each reference is the mean of two renders of
    ref_spp / 2 with seeds ref_seed and ref_seed + 1 (the same cost), kept as ref_halves, so
    that each engine's own seed-to-seed noise can be shown beside the references' agreement."""
    if halves:
        ref_halves = {e: [render(e, samples=ref_spp // 2, seed=ref_seed + k)[0] for k in range(2)] for e in ENGINES}
        refs = {e: 0.5 * (a + b) for e, (a, b) in ref_halves.items()}
    else:
        ref_halves = None
        refs = {e: render(e, samples=ref_spp, seed=ref_seed)[0] for e in ENGINES}
    ref = 0.5 * (refs["PATHLIGHT"] + refs["CYCLES"])
    floor = rel_mse(refs["PATHLIGHT"], refs["CYCLES"]) / 4.0
    raw = {e: [] for e in ENGINES}
    renders = {e: [] for e in ENGINES}  # each budget's per-render errors
    for budget in times:
        per = {e: [] for e in ENGINES}
        for k in range(repeats(budget)):
            for e in ENGINES:
                img, _ = render(e, samples=1_000_000, time_limit=budget, seed=1 + k)
                per[e].append(rel_mse(img, ref))
        for e in ENGINES:
            raw[e].append(float(np.mean(per[e])))
            renders[e].append(per[e])
    errors = {e: [above_floor(x, floor) for x in raw[e]] for e in ENGINES}
    out = dict(refs=refs, errors=errors, raw=raw, floor=floor, pooled=pooled_ratio(renders, times, floor),
               renders=renders)
    if ref_halves is not None:
        out["ref_halves"] = ref_halves
    return out


def plot_errors(results, times, path, width=4.2, title_size=10, legend_size=8):
    """A log-log plot of each scene's error against time, one panel per scene, written to
    `path`; False where matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, axes = plt.subplots(1, len(results), figsize=(width * len(results), 3.4))
    for ax, (name, r) in zip(np.atleast_1d(axes), results.items()):
        for e, style in zip(ENGINES, ("o-", "s--")):
            ax.loglog(times, r["errors"][e], style, label=e.title())
        ax.axhline(r["floor"], color="grey", ls=":", label="reference floor (subtracted)")
        ax.set_title(name, fontsize=title_size)
        ax.set_xlabel("render time (s)")
        ax.set_ylabel("relative MSE")
        ax.legend(fontsize=legend_size)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
