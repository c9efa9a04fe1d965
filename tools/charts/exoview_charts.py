#!/usr/bin/python3
"""Charts of the evaluation (docs/evaluation.md) from exoview_eval's JSON lines, with matplotlib.

    tools/charts/exoview_charts.py RESULTS.jsonl [MORE.jsonl ...] --out DIR [--only NAME ...]

Reads every line whose "bench" is "eval" (nested objects such as config/quality/speed are
flattened: a key is found at any depth, first match wins) and writes, when the lines hold data for
them:
  eval_store.png        MSSIM vs view-store size (tag sweep_store), one line per scene;
  eval_sweeps.png       MSSIM vs R_max, lambda, cell size, delta_tau_sum (tags sweep_*);
  eval_voxel.png        MSSIM vs integrate CPU ms per frame over the TSDF voxel size, near and
                        scene-wide test poses (tags voxel_fixedlod, voxel_defaultlod, gt_ref);
  eval_speed_error.png  integrate + plan ms per input frame vs 1 - MSSIM, per policy (TSDF proxy).
A chart without data is not written (and says so).
"""
import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from jsonl import read_jsonl  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FuncFormatter, MaxNLocator  # noqa: E402

SCENES = ["village/flyover", "apartment/walk"]
COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#7f7f7f", "#000000"]


def flatten(obj, out=None):
    """Every key at any depth (first occurrence wins), like a search of the flat JSON text."""
    out = {} if out is None else out
    for k, v in obj.items():
        if isinstance(v, dict):
            flatten(v, out)
        elif k not in out:
            out[k] = v
    # Top-level keys win over nested ones of the same name.
    for k, v in obj.items():
        if not isinstance(v, dict):
            out[k] = v
    return out


def load(paths):
    return [flatten(d) for _, _, d in read_jsonl(paths, "exoview_charts")
            if d.get("bench") == "eval"]


def num(r, k):
    v = r.get(k)
    return float(v) if isinstance(v, (int, float)) else None


def style(ax, title, xlabel, ylabel):
    ax.set_title(title, fontsize=11)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.yaxis.set_major_locator(MaxNLocator(nbins=6))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _: f"{y:.2f}" if abs(y) < 10 else f"{y:.0f}"))


def log2_ticks(ax, values):
    """Log-2 x axis with the measured values as ticks (store sizes, R_max)."""
    ax.set_xscale("log", base=2)
    vals = sorted(set(values))
    ax.set_xticks(vals)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())


def chart_store(rows, path):
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    xs_all = []
    for i, sc in enumerate(SCENES):
        pts = sorted((num(r, "store"), num(r, "mssim")) for r in rows
                     if r.get("dataset") == sc and r.get("tag") == "sweep_store")
        if pts:
            ax.plot(*zip(*pts), "o-", color=COLORS[i], label=sc)
            xs_all += [p[0] for p in pts]
    if not xs_all:
        plt.close(fig)
        return False
    log2_ticks(ax, xs_all)
    style(ax, "MSSIM vs view store size (online planner, TSDF proxy)", "store size (views, log scale)",
          "MSSIM")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


SWEEPS = [("sweep_r_max", "r_max", "R_max (references per cell, log scale)", True),
          ("sweep_lambda", "lambda", "λ (directional vs positional weight)", False),
          ("sweep_cell", "cell_m", "cell size (m)", False),
          ("sweep_dts", "delta_tau_sum", "Δτ_sum (store acceptance margin)", False)]


def chart_sweeps(rows, path):
    fig, axes = plt.subplots(2, 2, figsize=(11.2, 7.2), dpi=100)
    any_data = False
    for ax, (tag, key, label, logx) in zip(axes.flat, SWEEPS):
        xs_all = []
        for i, sc in enumerate(SCENES):
            pts = sorted((num(r, key), num(r, "mssim")) for r in rows
                         if r.get("dataset") == sc and r.get("tag") == tag)
            if pts:
                ax.plot(*zip(*pts), "o-", color=COLORS[i], label=sc)
                xs_all += [p[0] for p in pts]
        any_data |= bool(xs_all)
        if logx and xs_all:
            log2_ticks(ax, xs_all)
        style(ax, f"MSSIM vs {label.split(' (')[0]}", label, "MSSIM")
        if xs_all:
            ax.legend(fontsize=8)
    if not any_data:
        plt.close(fig)
        return False
    fig.suptitle("Planner parameter sweeps (online policy, TSDF proxy)", fontsize=12)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def chart_voxel(rows, path):
    fig, axes = plt.subplots(1, 2, figsize=(11.2, 4.4), dpi=100)
    any_data = False
    for ax, tset in zip(axes, ["near", "scene"]):
        xs_all = []
        for i, sc in enumerate(SCENES):
            name = sc.split("/")[0]
            for tag, filled in (("voxel_fixedlod", True), ("voxel_defaultlod", False)):
                pts = sorted((num(r, "integrate_cpu_ms_median"), num(r, "mssim"), num(r, "voxel_m"))
                             for r in rows if r.get("dataset") == sc and r.get("tag") == tag
                             and r.get("test_poses") == tset)
                if not pts:
                    continue
                xs_all += [p[0] for p in pts]
                if filled:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color=COLORS[i],
                            label=f"{name}, fixed cell-id LOD")
                    for x, y, v in pts:
                        ax.annotate(f"{100 * v:.3g} cm", (x, y), textcoords="offset points",
                                    xytext=(4, -11), fontsize=7, color=COLORS[i])
                else:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", mfc="none",
                            color=COLORS[i], markersize=9, label=f"{name}, default LOD")
            # The same protocol with the ground-truth mesh as proxy: the ceiling.
            xs = [num(r, "integrate_cpu_ms_median") for r in rows
                  if r.get("dataset") == sc and r.get("tag") == "voxel_fixedlod"]
            for r in rows:
                if (xs and r.get("dataset") == sc and r.get("tag") == "gt_ref"
                        and r.get("test_poses") == tset):
                    ax.hlines(num(r, "mssim"), min(xs), max(xs), colors=COLORS[i], linestyles="--",
                              alpha=0.6, label=f"{name}, ground-truth mesh as proxy")
        if xs_all:
            any_data = True
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
            ax.xaxis.set_minor_formatter(FuncFormatter(
                lambda x, _: f"{x:g}" if str(int(round(x)))[0] in "25" else ""))
            ax.legend(fontsize=7, loc="lower right" if tset == "near" else "upper right")
        style(ax, f"MSSIM ({tset} test poses) vs TSDF voxel size",
              "integrate CPU per input frame, median (ms, log scale)", "MSSIM")
    if not any_data:
        plt.close(fig)
        return False
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def chart_speed_error(rows, path):
    fig, axes = plt.subplots(1, 2, figsize=(11.2, 4.2), dpi=100)
    any_data = False
    for ax, sc in zip(axes, SCENES):
        series = {}
        for r in rows:
            if r.get("dataset") != sc or r.get("proxy") != "tsdf":
                continue
            tag = r.get("tag", "")
            name = r.get("policy", "?")
            if tag in ("sweep_store", "sweep_r_max"):
                name = f"online, {tag[6:]} sweep"
            elif tag.startswith("sweep"):
                continue
            ms = (num(r, "integrate_ms_median") or 0) + (num(r, "plan_ms_median") or 0)
            series.setdefault(name, []).append((ms, 1 - num(r, "mssim")))
        for i, (name, pts) in enumerate(sorted(series.items())):
            ax.plot(*zip(*sorted(pts)), "o", color=COLORS[i % len(COLORS)], label=name)
        any_data |= bool(series)
        style(ax, f"Speed vs error: {sc}", "integrate + plan per input frame, median (ms)",
              "1 − MSSIM (lower is better)")
        ax.set_xlim(left=0)
        if series:
            ax.legend(fontsize=7)
    if not any_data:
        plt.close(fig)
        return False
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


CHARTS = {"eval_store": chart_store, "eval_sweeps": chart_sweeps, "eval_voxel": chart_voxel,
          "eval_speed_error": chart_speed_error}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", nargs="+", help="JSON-lines files of exoview_eval")
    ap.add_argument("--out", required=True, help="folder for the PNGs")
    ap.add_argument("--only", nargs="*", choices=sorted(CHARTS), help="charts to draw (default all)")
    a = ap.parse_args()
    rows = load(a.results)
    os.makedirs(a.out, exist_ok=True)
    for name in a.only or sorted(CHARTS):
        path = os.path.join(a.out, name + ".png")
        if CHARTS[name](rows, path):
            print(f"exoview_charts: wrote {path}")
        else:
            print(f"exoview_charts: no data for {name} in {', '.join(a.results)}")


if __name__ == "__main__":
    main()
