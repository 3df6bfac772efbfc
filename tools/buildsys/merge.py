"""`merge`: partial EXR renders of one frame (farm splitting) merged into one, weighted by
their sample counts, under .venv's Python (`build.py _merge`)."""

import json
import os
import re
import sys
from pathlib import Path

from .common import ROOT, VENV_PY, Lock, UserError, run_internal
from .setup import ensure_setup

MERGE_SAMPLES = "Pathlight Samples"  # header attributes the add-on stamps into its renders
MERGE_OFFSET = "Pathlight Sample Offset"
COUNT_CHANNEL = re.compile(r"(^|\.)(Sample ?Count|Samples)(\.[A-Z])?$", re.IGNORECASE)
# Cryptomatte ranked (id, coverage) pairs: merged by id, not averaged (docs/design/passes.md).
CRYPTO_CHANNEL = re.compile(r"^(?P<layer>(.*\.)?Crypto(Object|Material|Asset))(?P<pass>\d\d)\.(?P<c>[rgba])$")


def cmd_merge(args):
    inputs = [Path(p) for p in args.inputs]
    for p in inputs:
        if not p.is_file():
            raise UserError(f"not found: {p}")
    out = Path(args.output)
    if out.suffix.lower() != ".exr":
        raise UserError("the merged output must be an .exr")
    if out.parent != Path("") and not out.parent.resolve().is_dir():
        raise UserError(f"output directory does not exist: {out.parent}")
    with Lock():
        ensure_setup()
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_merge",
            json.dumps({"inputs": [str(p.resolve()) for p in inputs], "output": str(out.resolve()),
                        "denoise": bool(getattr(args, "denoise", False))})]
    sys.stdout.flush()
    os.execve(str(VENV_PY), argv, dict(os.environ))  # numpy and OpenEXR only: no core, no bpy


def internal_merge(argv):
    """`build.py _merge OPTIONS_JSON`: the `merge` command, under .venv's Python."""
    def merge():
        opts = json.loads(argv[0])
        info = merge_exr(opts["inputs"], opts["output"], denoise=opts.get("denoise", False))
        for line in info.get("denoise", []):
            print(line, flush=True)
        ranges = ", ".join(f"[{a}, {a + n})" if a is not None else f"{n}" for a, n in info["ranges"])
        print(f"Merged {len(opts['inputs'])} renders ({info['samples']} samples: {ranges}; "
              f"weights: {info['weights']}) -> {opts['output']}", flush=True)
    run_internal(merge)


def merge_exr(inputs, output, denoise=False):
    """Merges EXR renders of one frame with disjoint sample ranges: every channel is the
    sample-weighted mean of the inputs' channels, a per-pixel sample-count channel (the
    "Sample Count" pass, when the files have one) is summed and weighs its pixels; without it
    each file weighs by its "Pathlight Samples" header attribute. denoise: denoise the merged
    Combined (pieces of a split frame never are) with Open Image Denoise (addon/denoise.py,
    Blender's library beside the installed bpy), guided by the merged Denoising Albedo and
    Normal where the files have them, and its Shadow Catcher pass as Cycles denoises it;
    "Noisy Image" and "Noisy Shadow Catcher" stay the merged noisy ones. Returns a summary
    dict ("denoise": its log lines)."""
    import numpy as np
    import OpenEXR
    parts = []
    for path in inputs:
        with OpenEXR.File(str(path)) as exr:
            header = dict(exr.header())
            channels = {name: np.array(ch.pixels, dtype=np.float32) for name, ch in exr.channels().items()}
        parts.append((path, header, channels))
    names = list(parts[0][2])
    shapes = {n: parts[0][2][n].shape for n in names}
    for path, _, channels in parts[1:]:
        if list(channels) != names or any(channels[n].shape != shapes[n] for n in names):
            raise UserError(f"{Path(path).name} has other channels or another resolution than "
                            f"{Path(parts[0][0]).name}")
    count_names = [n for n in names if COUNT_CHANNEL.search(n)]
    ranges, file_samples = [], []
    for path, header, _ in parts:
        samples = header.get(MERGE_SAMPLES)
        offset = header.get(MERGE_OFFSET)
        if samples is None and not count_names:
            raise UserError(f"{Path(path).name} has neither a Sample Count pass nor a "
                            f"'{MERGE_SAMPLES}' attribute: render it with Pathlight")
        n = int(float(samples)) if samples is not None else None
        ranges.append((int(float(offset)) if offset is not None else None, n))
        file_samples.append(n)
    known = sorted((a, n) for a, n in ranges if a is not None and n is not None)
    for (a0, n0), (a1, _) in zip(known, known[1:]):
        if a1 < a0 + n0:
            raise UserError(f"sample ranges [{a0}, {a0 + n0}) and [{a1}, ...) overlap: the "
                            "merged render would count those samples twice (use --sample-offset)")

    def weight(i, shape):
        channels = parts[i][2]
        if count_names:
            w = channels[count_names[0]].astype(np.float64)
        else:
            w = np.full(shape[:2], float(file_samples[i]))
        return w.reshape(w.shape + (1,) * (len(shape) - w.ndim))

    merged = _merge_cryptomatte(parts, names, weight)
    for name in names:
        if name in merged:
            continue
        if name in count_names:
            merged[name] = sum(p[2][name].astype(np.float64) for p in parts).astype(np.float32)
            continue
        shape = shapes[name]
        num = np.zeros(shape, np.float64)
        den = np.zeros(shape[:2] + (1,) * (len(shape) - 2), np.float64)
        for i, part in enumerate(parts):
            w = weight(i, shape)
            num += w * part[2][name]
            den += w
        merged[name] = np.where(den > 0, num / np.maximum(den, 1e-300), 0.0).astype(np.float32)
    notes = _denoise_merged(merged) if denoise else []
    header = {k: v for k, v in parts[0][1].items()
              if k in ("compression", "pixelAspectRatio", "multiView") or not k[:1].islower()
              or k.startswith("cryptomatte/")}  # (multiView: a stereo render's view names)
    total = sum(n for n in file_samples if n is not None) if all(file_samples) else None
    if total is not None:
        header[MERGE_SAMPLES] = str(total)
        header[MERGE_OFFSET] = str(min(a for a, _ in ranges if a is not None)) \
            if all(a is not None for a, _ in ranges) else "0"
    OpenEXR.File(header, merged).write(str(output))
    return {"samples": total, "ranges": ranges,
            "weights": "per-pixel sample counts" if count_names else "samples per file", "denoise": notes}


def _guide(merged, prefix, name, chans):
    """(H, W, 3) of pass `name` under layer prefix `prefix`, grouped or per channel; or None."""
    import numpy as np
    if merged.get(prefix + name) is not None and merged[prefix + name].ndim == 3:
        return merged[prefix + name][..., :3]
    keys = [f"{prefix}{name}.{c}" for c in chans]
    if all(k in merged for k in keys):
        return np.stack([merged[k] for k in keys], -1)
    return None


def _denoise_merged(merged):
    """Denoises every Combined (RGBA) in `merged` in place, and with it its layer's Shadow
    Catcher pass where the files have one (as Cycles: the normal guide and a 0.5 albedo); the
    Noisy Image and Noisy Shadow Catcher passes stay as merged. Returns log lines."""
    import importlib.util
    import numpy as np
    spec = importlib.util.spec_from_file_location("pathlight_denoise", ROOT / "addon" / "denoise.py")
    oidn = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(oidn)  # (ctypes and numpy only: no Blender)
    lines = []
    for name in list(merged):
        if not (name == "RGBA" or name.endswith("Combined")) or merged[name].ndim != 3:
            continue
        prefix = name[:-len("Combined")] if name.endswith("Combined") else ""
        albedo = _guide(merged, prefix, "Denoising Albedo", "RGB")
        normal = _guide(merged, prefix, "Denoising Normal", "XYZ") if albedo is not None else None
        image = np.ascontiguousarray(merged[name], np.float32).copy()
        jobs = [(name, image, True)]
        catcher = _guide(merged, prefix, oidn.SHADOW_CATCHER, "RGB") if name != "RGBA" else None
        if catcher is not None:
            jobs.append((prefix + oidn.SHADOW_CATCHER, np.ascontiguousarray(catcher, np.float32).copy(), False))
        try:
            seconds = oidn.denoise_many([(img, use_albedo) for _, img, use_albedo in jobs], albedo, normal)
        except (oidn.DenoiseError, ValueError) as e:
            lines.append(f"{name}: not denoised: {e}")
            continue
        for key, img, _ in jobs:
            if merged.get(key) is not None and merged[key].ndim == 3:
                merged[key] = img
            else:  # (channels stored one by one)
                for i, c in enumerate("RGB"):
                    merged[f"{key}.{c}"] = np.ascontiguousarray(img[..., i])
        used = "colour + albedo + normal" if normal is not None else "colour + albedo" if albedo is not None \
            else "colour only (no Denoising Data passes in the files)"
        also = f" with its {oidn.SHADOW_CATCHER} pass" if catcher is not None else ""
        lines.append(f"{name}: denoised{also} ({used}) in {seconds:.2f} s")
    if not lines:
        lines.append("nothing denoised: no Combined / RGBA channels")
    return lines


def _merge_cryptomatte(parts, names, weight):
    """{channel: merged pixels} of the Cryptomatte passes (CryptoObject00.r, ...): per pixel,
    each id's coverage is the sample-weighted mean of its coverage in the inputs (0 where an
    input did not rank it); the ids are ranked again by it, heaviest first, and as many kept
    as the passes have slots (as the renderer itself keeps them)."""
    import numpy as np
    layers = {}
    for name in names:
        m = CRYPTO_CHANNEL.match(name)
        if m:
            layers.setdefault(m["layer"], set()).add(int(m["pass"]))
    out = {}
    for layer, passes in layers.items():
        passes = sorted(passes)
        slots = [(f"{layer}{p:02d}.{i}", f"{layer}{p:02d}.{c}") for p in passes for i, c in (("r", "g"), ("b", "a"))]
        if any(n not in names for pair in slots for n in pair):
            continue  # not Cycles' layout: averaged like any other channel
        shape = parts[0][2][slots[0][0]].shape
        ids, covs, den = [], [], np.zeros(shape, np.float64)
        for i, part in enumerate(parts):
            w = weight(i, shape)
            den += w
            for id_name, cov_name in slots:
                ids.append(part[2][id_name])
                covs.append(part[2][cov_name].astype(np.float64) * w)
        ids, covs = np.stack(ids), np.stack(covs)
        total = np.zeros(covs.shape, np.float64)
        for k in range(len(ids)):
            same = ids == ids[k]
            total[k] = np.where(same, covs, 0.0).sum(axis=0)
            if k:  # an id counts once: at its first entry
                total[k] = np.where(same[:k].any(axis=0), 0.0, total[k])
        total = np.where(ids != 0, total, 0.0)  # 0: no id
        order = np.argsort(-total, axis=0, kind="stable")[:len(slots)]
        ranked_ids = np.take_along_axis(ids, order, axis=0)
        ranked = np.take_along_axis(total, order, axis=0) / np.maximum(den, 1e-300)
        for s, (id_name, cov_name) in enumerate(slots):
            keep = ranked[s] > 0
            out[id_name] = np.where(keep, ranked_ids[s], 0.0).astype(np.float32)
            out[cov_name] = np.where(keep, ranked[s], 0.0).astype(np.float32)
    return out
