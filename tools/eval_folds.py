#!/usr/bin/env python3
"""Ten-fold 7-Scenes evaluation (issue 15, item 4).

Runs `exoview_eval --sevenscenes DIR --holdout_offset J` for each fold J (frame k held out when
k mod 10 == J; held-out frames whose colour image is byte-identical to an ingested frame are
dropped by the eval), one run at a time, and prints mean +- spread over the folds per policy and
store: SSIM / PSNR of the filled frame, MS-SSIM, GMSD, unfilled SSIM, coverage, render ms.

  tools/eval_folds.py --eval build/server/eval/exoview_eval \\
      --data /work/shared/data/7scenes-redkitchen --out /tmp/folds \\
      --stores 50,100,200 --policies online,every_n,min_distance,all [-- extra eval flags]
  tools/eval_folds.py --out /tmp/folds --summarize   # only re-read the fold files

Each fold's JSON lines go to OUT/fold_J.jsonl (a finished fold is not run again unless --force);
the summary to OUT/summary.json. Spread = sample standard deviation over folds (and min..max).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

METRICS = [
    ("mssim", ("quality", "mssim")),
    ("psnr", ("quality", "psnr")),
    ("ms_ssim", ("perceptual", "ms_ssim")),
    ("gmsd", ("perceptual", "gmsd")),
    ("mssim_unfilled", ("quality", "mssim_unfilled")),
    ("coverage", ("quality", "coverage")),
    ("render_ms", ("speed", "render_ms_median")),
    # oracle per-channel gain fitted to the ground truth (exposure / white-balance share)
    ("mssim_gain_fit", ("attribution", "mssim_gain_fit")),
    ("psnr_gain_fit", ("attribution", "psnr_gain_fit")),
]


def run_fold(args, fold, extra):
    path = os.path.join(args.out, f"fold_{fold}.jsonl")
    if os.path.exists(path) and not args.force:
        with open(path) as f:
            if any(json.loads(l).get("bench") == "eval_split" for l in f if l.strip()):
                print(f"fold {fold}: {path} exists, kept", file=sys.stderr)
                return path
    cmd = ["nice", args.eval, "--sevenscenes", args.data, "--holdout_offset", str(fold),
           "--store", args.stores, "--policies", args.policies] + extra
    print(f"fold {fold}: {' '.join(cmd)}", file=sys.stderr)
    t0 = time.time()
    with open(path + ".tmp", "w") as out, open(os.path.join(args.out, f"fold_{fold}.log"), "w") as log:
        rc = subprocess.call(cmd, stdout=out, stderr=log)
    if rc != 0:
        sys.exit(f"fold {fold}: exoview_eval exited {rc} (see {args.out}/fold_{fold}.log)")
    os.replace(path + ".tmp", path)
    print(f"fold {fold}: {time.time() - t0:.0f} s", file=sys.stderr)
    return path


def load(path):
    rows, split = [], None
    with open(path) as f:
        for line in f:
            if not line.strip():
                continue
            d = json.loads(line)
            if d.get("bench") == "eval":
                rows.append(d)
            elif d.get("bench") == "eval_split":
                split = d
    return rows, split


def stats(values):
    v = [x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not v:
        return None
    mean = sum(v) / len(v)
    sd = math.sqrt(sum((x - mean) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return {"mean": mean, "sd": sd, "min": min(v), "max": max(v), "n": len(v)}


def summarize(paths):
    groups = {}
    per_fold = {}  # (policy, store, tag) -> {fold: {metric: value}} for paired deltas
    splits = []
    for fold, path in paths:
        rows, split = load(path)
        splits.append({"fold": fold, **(split or {})})
        for d in rows:
            c = d["config"]
            store = "all" if c["policy"] in ("all", "all_frames", "vertex_color") else c["store"]
            key = (c["policy"], store, c.get("refs", ""), d.get("tag", ""))
            g = groups.setdefault(key, {m: [] for m, _ in METRICS})
            for m, (a, b) in METRICS:
                g[m].append(d.get(a, {}).get(b))
            per_fold.setdefault((c["policy"], store, d.get("tag", "")), {})[fold] = {
                m: d.get(a, {}).get(b) for m, (a, b) in METRICS}
    out = []
    for (policy, store, refs, tag), g in sorted(groups.items(),
                                               key=lambda kv: (1e9 if kv[0][1] == "all" else kv[0][1], kv[0][3] != "main", kv[0][3], kv[0][0])):
        row = {"policy": policy, "store": store, "refs": refs, "tag": tag,
               **{m: stats(g[m]) for m, _ in METRICS}}
        # A variant (tag other than main/baseline): paired per-fold difference to the main row of
        # the same policy and store.
        base = per_fold.get((policy, store, "main"))
        mine = per_fold.get((policy, store, tag))
        if tag not in ("main", "baseline") and base and mine:
            row["delta_vs_main"] = {
                m: stats([mine[f][m] - base[f][m] for f in mine
                          if f in base and mine[f][m] is not None and base[f][m] is not None])
                for m, _ in METRICS}
        out.append(row)
    return out, splits


def print_table(summary):
    cols = [m for m, _ in METRICS]
    print("| policy | store | variant | folds | " + " | ".join(cols) + " |")
    print("|---|---|---|---|" + "---|" * len(cols))
    for r in summary:
        cells = []
        for m in cols:
            s = r[m]
            if s is None:
                cells.append("-")
            elif m in ("psnr", "psnr_gain_fit"):
                cells.append(f"{s['mean']:.2f} ± {s['sd']:.2f}")
            elif m == "render_ms":
                cells.append(f"{s['mean']:.0f}")
            else:
                cells.append(f"{s['mean']:.4f} ± {s['sd']:.4f}")
        n = r["mssim"]["n"] if r["mssim"] else 0
        tag = "" if r["tag"] in ("main", "baseline") else r["tag"]
        print(f"| {r['policy']} | {r['store']} | {tag} | {n} | " + " | ".join(cells) + " |")
    deltas = [r for r in summary if "delta_vs_main" in r]
    if deltas:
        print("\nPaired difference to the default blend (same policy, store and fold), mean ± sd over folds:")
        print("| policy | store | variant | folds | " + " | ".join(cols) + " |")
        print("|---|---|---|---|" + "---|" * len(cols))
        for r in deltas:
            cells = []
            for m in cols:
                s = r["delta_vs_main"][m]
                if s is None:
                    cells.append("-")
                elif m in ("psnr", "psnr_gain_fit"):
                    cells.append(f"{s['mean']:+.2f} ± {s['sd']:.2f}")
                elif m == "render_ms":
                    cells.append(f"{s['mean']:+.0f}")
                else:
                    cells.append(f"{s['mean']:+.4f} ± {s['sd']:.4f}")
            n = r["delta_vs_main"]["mssim"]["n"] if r["delta_vs_main"]["mssim"] else 0
            print(f"| {r['policy']} | {r['store']} | {r['tag']} | {n} | " + " | ".join(cells) + " |")


def main():
    argv = sys.argv[1:]
    extra = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1:]
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--eval", default="build/server/eval/exoview_eval")
    p.add_argument("--data", default="/work/shared/data/7scenes-redkitchen")
    p.add_argument("--out", required=True)
    p.add_argument("--folds", default="0-9", help="e.g. 0-9 or 0,3,7")
    p.add_argument("--stores", default="50,100,200")
    p.add_argument("--policies", default="online,every_n,min_distance,all")
    p.add_argument("--summarize", action="store_true", help="only summarise existing fold files")
    p.add_argument("--force", action="store_true", help="rerun folds whose file exists")
    args = p.parse_args(argv)
    if "-" in args.folds:
        a, b = args.folds.split("-")
        folds = list(range(int(a), int(b) + 1))
    else:
        folds = [int(x) for x in args.folds.split(",")]
    if any(f < 0 or f > 9 for f in folds):
        sys.exit("--folds must be within 0..9")
    os.makedirs(args.out, exist_ok=True)
    paths = []
    for fold in folds:
        path = os.path.join(args.out, f"fold_{fold}.jsonl")
        if args.summarize:
            if os.path.exists(path):
                paths.append((fold, path))
            continue
        paths.append((fold, run_fold(args, fold, extra)))
    if not paths:
        sys.exit(f"no fold files in {args.out}")
    summary, splits = summarize(paths)
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump({"folds": splits, "configs": summary, "extra_flags": extra}, f, indent=1)
    print_table(summary)
    tv = [s.get("test_views") for s in splits]
    dd = [s.get("dropped_duplicate_colour") for s in splits]
    print(f"\nfolds {[s['fold'] for s in splits]}; test views per fold {tv}; "
          f"dropped duplicate-colour frames {dd}")


if __name__ == "__main__":
    main()
