#!/usr/bin/python3
"""Exploration over time (docs/control.md) from exoview_explore_bench's JSON lines.

    tools/charts/explore_chart.py RESULTS.jsonl [MORE.jsonl ...] --out explore.png

Reads the summary lines ("bench": "explore"; the last one per (scene, policy) wins) and draws,
per scene, two panels over simulated flight time: the coverage at tau >= tau_max/2
(mean_coverage_at_s, with 0 at t = 0) and the MSSIM of the view planner's store at the held-out
test poses (mean_mssim_at_s; a line without it is left out of that panel). One line per policy,
the number of runs in the legend. A scene without any line is not drawn; no line at all is an
error (exit 1).
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from jsonl import read_jsonl  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

POLICIES = [("autonomous", "autonomous (coverage-driven)", "#1f77b4"),
            ("frontier", "nearest frontier", "#d62728"),
            ("scripted", "scripted walk / fly-over", "#2ca02c")]
SCENES = ["apartment", "village"]


def load(paths):
    """{(scene, policy): summary line}, the last line per key wins."""
    rows = {}
    for _, _, d in read_jsonl(paths, "explore_chart"):
        if d.get("bench") != "explore":
            continue
        rows[(d.get("scene", "?"), d.get("policy", "?"))] = d
    return rows


def series(d, key, zero):
    """Sorted (t, value) pairs of a {"seconds": value} object; (0, zero) first if given."""
    pts = sorted((float(t), v) for t, v in (d.get(key) or {}).items() if v is not None)
    if zero is not None and pts and pts[0][0] > 0:
        pts.insert(0, (0.0, zero))
    return pts


def draw(rows, path):
    scenes = [s for s in SCENES if any(k[0] == s for k in rows)]
    scenes += sorted({k[0] for k in rows} - set(scenes))
    if not scenes:
        sys.exit("explore_chart: no 'explore' summary lines in the input")
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 3.6 * len(scenes)), squeeze=False)
    for i, scene in enumerate(scenes):
        cov_ax, ssim_ax = axes[i]
        drawn_ssim = False
        for policy, label, colour in POLICIES:
            d = rows.get((scene, policy))
            if d is None:
                continue
            name = f"{label} ({d.get('runs', '?')} runs)"
            cov = series(d, "mean_coverage_at_s", 0.0)
            if cov:
                cov_ax.plot([t for t, _ in cov], [100 * v for _, v in cov], "-o", ms=3,
                            color=colour, label=name)
            ssim = series(d, "mean_mssim_at_s", None)
            if ssim:
                ssim_ax.plot([t for t, _ in ssim], [v for _, v in ssim], "-o", ms=3,
                             color=colour, label=name)
                drawn_ssim = True
        metric = rows.get((scene, "autonomous"), next(v for k, v in rows.items() if k[0] == scene))
        m = metric.get("metric") or {}
        cov_ax.axhline(80, color="#999999", lw=0.8, ls="--")
        cov_ax.set_title(f"{scene}: surface at tau >= 2 (cells {m.get('cell_m', '?')} m, "
                         f"d_max {m.get('d_max_m', 0):.3g} m)", fontsize=10)
        cov_ax.set_xlabel("simulated flight time (s)")
        cov_ax.set_ylabel("coverage (% of surface area)")
        cov_ax.set_ylim(0, 100)
        cov_ax.grid(alpha=0.3)
        cov_ax.legend(fontsize=8, loc="upper left")
        ssim_ax.set_title(f"{scene}: MSSIM at held-out test poses "
                          f"({metric.get('test_views', '?')} poses, store "
                          f"{metric.get('store', '?')} views)", fontsize=10)
        ssim_ax.set_xlabel("simulated flight time (s)")
        ssim_ax.set_ylabel("MSSIM")
        ssim_ax.grid(alpha=0.3)
        if drawn_ssim:
            ssim_ax.legend(fontsize=8, loc="lower right")
        else:
            ssim_ax.text(0.5, 0.5, "no MSSIM in the input", ha="center", transform=ssim_ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return scenes


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", help="exoview_explore_bench JSON lines")
    ap.add_argument("--out", required=True, help="PNG to write")
    args = ap.parse_args()
    scenes = draw(load(args.inputs), args.out)
    print(f"explore_chart: wrote {args.out} ({', '.join(scenes)})")


if __name__ == "__main__":
    main()
