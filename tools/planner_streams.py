#!/usr/bin/python3
"""Planner benchmark over realistic streams (issue 22).

Runs `exoview_eval` once per (scene, stream, seed) -- one ingest of the stream, every policy at
every store size, both test-pose sets on the same stores -- and summarises the JSON lines: per
(scene, stream, test poses, store, policy) the mean and sample sd over seeds of SSIM / PSNR /
coverage / unfilled SSIM, the stored views and bytes and the planning CPU ms per frame, and the
paired difference online - baseline per seed with a verdict (win: online better on every seed,
loss: worse on every seed, tie: mixed).

  tools/planner_streams.py --eval build/server/eval/exoview_eval --out /tmp/ps \\
      --scenes apartment,village --streams drone,handheld --seeds 1,2,3 \\
      --stores 50,100,200,400 --frames 5000 -- --frame_w 320 --frame_h 240 \\
      --test_w 160 --test_h 120 --test_views 24 --test_poses near,scene
  tools/planner_streams.py --out /tmp/ps --summarize [--chart docs/img/planner_streams.png]

Seed s: --scene_seed s (scene layout and textures; the stream's seed follows it) and
--test_seed 10 + s. A finished run's file OUT/SCENE_STREAM_sSEED.jsonl is kept (--force reruns).
The summary goes to OUT/summary.json and stdout (a markdown table per scene / test poses).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "charts"))
from jsonl import read_jsonl  # noqa: E402

POLICIES = "online,every_n,every_n_online,reservoir,min_distance,keyframe"
ORACLES = {"every_n", "offline_greedy", "all_frames"}  # know the stream's length / future
LABEL = {
    "online": "online planner (thesis 3.6)",
    "online_novelty": "online planner, novelty-weighted φ_p",
    "online_dispersion": "online planner, pose dispersion first (coverage guard)",
    "every_n": "every-N (oracle: knows the length)",
    "every_n_online": "every-N, progressive decimation",
    "reservoir": "reservoir sampling",
    "min_distance": "min-distance",
    "keyframe": "keyframes (InpaintFusion rule)",
    "offline_greedy": "offline greedy (oracle)",
    "vertex_color": "vertex colour (no views)",
}


def run_file(out, scene, stream, seed):
    return os.path.join(out, f"{scene}_{stream}_s{seed}.jsonl")


def run_one(args, scene, stream, seed, extra):
    path = run_file(args.out, scene, stream, seed)
    if os.path.exists(path) and not args.force:
        print(f"{path} exists, kept", file=sys.stderr)
        return
    cmd = ["nice", args.eval, "--scene", scene, "--traj", stream, "--frames", str(args.frames),
           "--scene_seed", str(seed), "--test_seed", str(10 + seed), "--store", args.stores,
           "--policies", args.policies] + extra
    print(" ".join(cmd), file=sys.stderr)
    t0 = time.time()
    log = os.path.join(args.out, f"{scene}_{stream}_s{seed}.log")
    with open(path + ".tmp", "w") as f, open(log, "w") as lf:
        rc = subprocess.call(cmd, stdout=f, stderr=lf)
    if rc != 0:
        sys.exit(f"planner_streams: exoview_eval exited {rc} (see {log})")
    os.replace(path + ".tmp", path)
    print(f"  {time.time() - t0:.0f} s", file=sys.stderr)


def mean_sd(v):
    if not v:
        return float("nan"), float("nan")
    m = sum(v) / len(v)
    sd = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return m, sd


def load(out):
    """[(scene, stream, seed, row)] of every eval line under OUT."""
    rows = []
    for name in sorted(os.listdir(out)):
        if not name.endswith(".jsonl") or "_s" not in name:
            continue
        base = name[:-len(".jsonl")]
        head, seed = base.rsplit("_s", 1)
        scene, stream = head.split("_", 1)
        for _, _, d in read_jsonl([os.path.join(out, name)], "planner_streams"):
            if d.get("bench") == "eval":
                rows.append((scene, stream, int(seed), d))
    return rows


def summarize(rows, metric):
    """{(scene, stream, poses): {policy: {store: {...}}}} with per-seed values kept."""
    acc = {}
    for scene, stream, seed, d in rows:
        pol = d["config"]["policy"]
        if pol == "vertex_color":
            continue
        if pol == "online" and d["config"].get("novelty_positional"):
            pol = "online_novelty"
        if pol == "online" and d["config"].get("dispersion"):
            pol = "online_dispersion"
        key = (scene, stream, d["test_poses"])
        store = d["config"]["store"]
        cell = acc.setdefault(key, {}).setdefault(pol, {}).setdefault(store, {})
        q = d["quality"]
        cell.setdefault("seeds", {})[seed] = {
            "mssim": q["mssim"], "psnr": q["psnr"], "coverage": q["coverage"],
            "mssim_unfilled": q["mssim_unfilled"], "views": d["views"],
            "store_bytes": d["memory"]["store_bytes"],
            "plan_cpu_ms": d.get("plan_cpu_ms", {}).get("median", d["speed"]["plan_ms_median"]),
            "plan_cpu_ms_p95": d.get("plan_cpu_ms", {}).get("p95", d["speed"]["plan_ms_p95"]),
            "frames": d["config"]["frames"], "online": d["config"].get("online", 1),
        }
    out = {}
    for key, pols in acc.items():
        for pol, stores in pols.items():
            for store, cell in stores.items():
                seeds = cell["seeds"]
                s = {"n_seeds": len(seeds), "seeds": sorted(seeds)}
                for k in ("mssim", "psnr", "coverage", "mssim_unfilled", "views", "store_bytes",
                          "plan_cpu_ms", "plan_cpu_ms_p95"):
                    m, sd = mean_sd([seeds[x][k] for x in sorted(seeds)])
                    s[k] = m
                    s[k + "_sd"] = sd
                s["per_seed_" + metric] = {str(x): seeds[x][metric] for x in sorted(seeds)}
                out.setdefault(key, {}).setdefault(pol, {})[store] = s
    return out


def verdicts(summary, metric):
    """{key: {store: {planner: {policy: paired planner - policy per seed}}}}: mean, sd, wins, verdict."""
    res = {}
    for key, pols in summary.items():
        for planner in ("online", "online_novelty", "online_dispersion"):
            for store, on in pols.get(planner, {}).items():
                for pol, stores in pols.items():
                    if pol == planner or store not in stores:
                        continue
                    b = stores[store]
                    seeds = [s for s in on["per_seed_" + metric] if s in b["per_seed_" + metric]]
                    d = [on["per_seed_" + metric][s] - b["per_seed_" + metric][s] for s in seeds]
                    if not d:
                        continue
                    m, sd = mean_sd(d)
                    wins = sum(1 for x in d if x > 0)
                    losses = sum(1 for x in d if x < 0)
                    verdict = "win" if wins == len(d) else "loss" if losses == len(d) else "tie"
                    res.setdefault(key, {}).setdefault(store, {}).setdefault(planner, {})[pol] = {
                        "delta": m, "delta_sd": sd, "wins": wins, "n": len(d), "verdict": verdict,
                        "rel_pct": 100 * m / b[metric] if b[metric] else float("nan")}
    return res


def print_tables(summary, ver, metric):
    online_baselines = ["every_n_online", "reservoir", "min_distance", "keyframe"]
    for key in sorted(summary):
        scene, stream, poses = key
        pols = summary[key]
        stores = sorted({s for p in pols.values() for s in p})
        order = [p for p in ["online", "online_novelty", "online_dispersion", "every_n", "every_n_online", "reservoir",
                             "min_distance", "keyframe", "offline_greedy"] if p in pols]
        any_cell = next(iter(next(iter(pols.values())).values()))
        print(f"\n### {scene} / {stream} / {poses} test poses ({any_cell['n_seeds']} seeds)\n")
        print("| policy | " + " | ".join(f"{metric} @ {s}" for s in stores) +
              " | views @ max | MB @ max | plan CPU ms/frame |")
        print("|---|" + "---|" * (len(stores) + 3))
        for p in order:
            cells = [f"{pols[p][s][metric]:.4f} ± {pols[p][s][metric + '_sd']:.4f}"
                     if s in pols[p] else "-" for s in stores]
            top = pols[p][max(pols[p])]
            print(f"| {LABEL.get(p, p)} | " + " | ".join(cells) +
                  f" | {top['views']:.0f} | {top['store_bytes'] / 2**20:.0f} |"
                  f" {top['plan_cpu_ms']:.3f} |")
    print(f"\n### The planners against the best online baseline and the oracle ({metric}, paired per"
          " seed: mean ± sd of planner - policy; win / loss = on every seed, else tie)\n")
    print("| scene / stream / poses | store | best online baseline | thesis planner vs it |"
          " novelty planner vs it | dispersion planner vs it | thesis vs oracle every-N |"
          " novelty vs oracle every-N | dispersion vs oracle every-N |")
    print("|---|---|---|---|---|---|---|---|---|")
    for key in sorted(ver):
        pols = summary[key]
        for store in sorted(ver[key]):
            cands = [(pols[p][store][metric], p) for p in online_baselines
                     if p in pols and store in pols[p]]
            if not cands:
                continue
            best = max(cands)[1]
            row = [f"{key[0]} / {key[1]} / {key[2]}", str(store), LABEL.get(best, best)]
            for planner, vs in (("online", best), ("online_novelty", best),
                                ("online_dispersion", best), ("online", "every_n"),
                                ("online_novelty", "every_n"), ("online_dispersion", "every_n")):
                v = ver[key][store].get(planner, {}).get(vs)
                row.append("-" if v is None else
                           f"{v['delta']:+.4f} ± {v['delta_sd']:.4f} {v['verdict']}"
                           f" ({v['rel_pct']:+.1f} %)")
            print("| " + " | ".join(row) + " |")


def chart(summary, path, metric):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = sorted(summary)
    rows = sorted({(k[0], k[2]) for k in keys})
    cols = sorted({k[1] for k in keys})
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(4.2 * len(cols), 3.2 * len(rows)),
                             squeeze=False)
    colors = {"online": "#d62728", "online_novelty": "#e377c2", "online_dispersion": "#17becf", "every_n": "#7f7f7f", "every_n_online": "#1f77b4",
              "reservoir": "#2ca02c", "min_distance": "#9467bd", "keyframe": "#ff7f0e",
              "offline_greedy": "#8c564b"}
    for i, (scene, poses) in enumerate(rows):
        for j, stream in enumerate(cols):
            ax = axes[i][j]
            pols = summary.get((scene, stream, poses))
            if not pols:
                ax.axis("off")
                continue
            for p, stores in sorted(pols.items()):
                xs = sorted(stores)
                ys = [stores[s][metric] for s in xs]
                es = [stores[s][metric + "_sd"] for s in xs]
                ax.errorbar(xs, ys, yerr=es, label=LABEL.get(p, p), color=colors.get(p),
                            linestyle="--" if p in ORACLES else "-", marker="o", ms=3,
                            capsize=2, lw=2.2 if p.startswith("online") else 1.2)
            ax.set_xscale("log", base=2)
            ax.set_xticks(xs)
            ax.set_xticklabels([str(x) for x in xs])
            n = next(iter(next(iter(pols.values())).values()))["n_seeds"]
            ax.set_title(f"{scene} {stream}, {poses} poses ({n} seeds)", fontsize=9)
            ax.set_xlabel("store (views)", fontsize=8)
            ax.set_ylabel(metric, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    h, lab = axes[0][0].get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=min(3, len(lab)), fontsize=8)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"chart: {path}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--eval", default="build/server/eval/exoview_eval")
    ap.add_argument("--out", required=True)
    ap.add_argument("--scenes", default="apartment,village")
    ap.add_argument("--streams", default="drone,handheld")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--stores", default="50,100,200,400")
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--policies", default=POLICIES)
    ap.add_argument("--metric", default="mssim", choices=["mssim", "psnr", "mssim_unfilled"])
    ap.add_argument("--summarize", action="store_true", help="only read OUT and summarise")
    ap.add_argument("--chart", help="write the quality-vs-store chart (PNG) here")
    ap.add_argument("--force", action="store_true")
    ap.add_argument("extra", nargs="*", help="after --: flags passed to exoview_eval")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    if not args.summarize:
        for seed in [int(s) for s in args.seeds.split(",") if s]:
            for scene in args.scenes.split(","):
                for stream in args.streams.split(","):
                    run_one(args, scene, stream, seed, args.extra)
    rows = load(args.out)
    if not rows:
        sys.exit(f"planner_streams: no eval lines under {args.out}")
    summary = summarize(rows, args.metric)
    ver = verdicts(summary, args.metric)
    print_tables(summary, ver, args.metric)
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump({"metric": args.metric,
                   "cells": [{"scene": k[0], "stream": k[1], "test_poses": k[2], "policy": p,
                              "store": s, **v}
                             for k, pols in sorted(summary.items())
                             for p, st in sorted(pols.items()) for s, v in sorted(st.items())],
                   "paired": [{"scene": k[0], "stream": k[1], "test_poses": k[2], "store": s,
                               "planner": pl, "vs": p, **v}
                              for k, sts in sorted(ver.items())
                              for s, pls in sorted(sts.items())
                              for pl, ps in sorted(pls.items()) for p, v in sorted(ps.items())]},
                  f, indent=1)
    if args.chart:
        chart(summary, args.chart, args.metric)


if __name__ == "__main__":
    main()
