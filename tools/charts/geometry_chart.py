#!/usr/bin/python3
"""Voxel-size chart of the TSDF proxy (docs/geometry.md) from geometry_bench's JSON lines, with matplotlib.

    tools/charts/geometry_chart.py RESULTS.jsonl [MORE.jsonl ...] --out docs/img/geometry_voxel_size.png

Reads every line whose "bench" is "geometry" (other lines, e.g. a run_info line, are skipped) and
draws three panels against the voxel size (log 2 x axis, ticks at the measured sizes in cm), one
line per dataset (and per alloc_stride when the lines hold more than one):
  time per input frame: integrate (wall median, solid) and incremental extraction (dashed), ms;
  triangles of the full mesh (log scale);
  geometric error, mm (log scale): mean vertex distance to the true surface (synthetic room) or
  mean |TSDF| at held-out depth points (7-Scenes).
Repeats of one (dataset, voxel, stride) are averaged. Exits 1 without data.
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from jsonl import read_jsonl  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FuncFormatter, NullLocator  # noqa: E402

COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#7f7f7f"]
# Error keys per dataset kind, in the order they are looked for.
ERR_KEYS = [("vertex_err_mm_mean", "vertex to true surface"),
            ("heldout_abs_sdf_mm_mean", "|TSDF| at held-out depth")]


def load(paths):
    rows = []
    for p, n, d in read_jsonl(paths, "geometry_chart"):
        if d.get("bench") != "geometry":
            continue
        for k in ("dataset", "voxel_m", "integrate_ms_median", "triangles"):
            if k not in d:
                sys.exit(f"geometry_chart: {p}:{n}: geometry line without \"{k}\"")
        rows.append(d)
    return rows


def series(rows):
    """{(dataset, stride): [(voxel_m, means of the numeric fields over repeats)]} sorted by voxel."""
    groups = {}
    for r in rows:
        key = (r["dataset"], r.get("alloc_stride", 0), float(r["voxel_m"]))
        groups.setdefault(key, []).append(r)
    out = {}
    for (ds, stride, vox), rs in sorted(groups.items()):
        mean = {}
        for k in rs[0]:
            vals = [r[k] for r in rs if isinstance(r.get(k), (int, float))]
            if vals and len(vals) == len(rs):
                mean[k] = sum(vals) / len(vals)
        out.setdefault((ds, stride), []).append((vox, mean))
    return out


def style(ax, title, ylabel, voxels):
    ax.set_title(title, fontsize=11)
    ax.set_xlabel("TSDF voxel size (cm, log scale)")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3, which="both")
    ax.set_xscale("log", base=2)
    ax.set_xticks(voxels)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{100 * x:g}"))
    ax.xaxis.set_minor_locator(NullLocator())


def log_y(ax):
    ax.set_yscale("log")
    fmt = FuncFormatter(lambda y, _: f"{y:g}" if y >= 1 else f"{y:.2g}")
    ax.yaxis.set_major_formatter(fmt)
    # Label the 2x and 5x minor ticks too (few decades on these axes).
    ax.yaxis.set_minor_formatter(FuncFormatter(
        lambda y, _: (f"{y:g}" if y >= 1 else f"{y:.2g}") if f"{y:.1e}"[0] in "25" else ""))
    ax.tick_params(axis="y", which="minor", labelsize=7)


def count_ticks(ax):
    """Triangle counts as 10k / 200k / 1M (majors and the 2x, 5x minors) instead of 10^n."""
    def fmt(y):
        for div, unit in ((1e6, "M"), (1e3, "k")):
            if y >= div:
                return f"{y / div:g}{unit}"
        return f"{y:g}"
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _: fmt(y)))
    ax.yaxis.set_minor_formatter(FuncFormatter(
        lambda y, _: fmt(y) if f"{y:.1e}"[0] in "25" else ""))
    ax.tick_params(axis="y", which="minor", labelsize=7)


def draw(rows, path):
    ser = series(rows)
    multi_stride = len({s for _, s in ser}) > 1
    voxels = sorted({v for pts in ser.values() for v, _ in pts})
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 4.4), dpi=100)
    handles = []
    for i, ((ds, stride), pts) in enumerate(sorted(ser.items())):
        c = COLORS[i % len(COLORS)]
        name = f"{ds}, alloc_stride {stride}" if multi_stride else ds
        xs = [v for v, _ in pts]
        (h,) = axes[0].plot(xs, [m["integrate_ms_median"] for _, m in pts], "o-", color=c,
                            label=f"{name}: integrate")
        handles.append(h)
        ext = [(v, m["extract_dirty_ms_median"]) for v, m in pts if "extract_dirty_ms_median" in m]
        if ext and any(e > 0 for _, e in ext):
            axes[0].plot(*zip(*ext), "s--", color=c, mfc="none", label=f"{name}: extract dirty")
        axes[1].plot(xs, [max(m["triangles"], 1) for _, m in pts], "o-", color=c, label=name)
        for key, what in ERR_KEYS:
            err = [(v, m[key]) for v, m in pts if key in m and m[key] > 0]
            if err:
                axes[2].plot(*zip(*err), "o-", color=c, label=f"{ds}: {what}")
                cov = [(v, m.get("coverage")) for v, m in pts if key in m]
                if all(cv is not None and cv < 0.9995 for _, cv in cov):
                    for (v, e), (_, cv) in zip(err, cov):
                        axes[2].annotate(f"{100 * cv:.1f} %", (v, e), textcoords="offset points",
                                         xytext=(-12, 6), fontsize=7, color=c)
                break
    style(axes[0], "Time per input frame (median)", "ms per frame (wall)", voxels)
    axes[0].set_ylim(bottom=0)
    axes[0].legend(fontsize=7)
    style(axes[1], "Triangles of the full mesh", "triangles (log scale)", voxels)
    count_ticks(axes[1])
    axes[1].legend(fontsize=7)
    style(axes[2], "Geometric error (mean)", "mm (log scale)", voxels)
    log_y(axes[2])
    lo, hi = axes[2].get_ylim()
    axes[2].set_ylim(lo, hi * 1.3)  # room for the coverage labels
    axes[2].legend(fontsize=7, title="labels: held-out coverage", title_fontsize=7, loc="center")
    frames = sorted({f"{r['dataset']}: {r.get('frames', '?')}" for r in rows})
    fig.suptitle("Sparse TSDF proxy vs voxel size (geometry_bench; integrated frames: "
                 + ", ".join(frames) + ")", fontsize=12)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", nargs="+", help="JSON-lines files of geometry_bench")
    ap.add_argument("--out", required=True, help="PNG to write")
    a = ap.parse_args()
    rows = load(a.results)
    if not rows:
        sys.exit(f"geometry_chart: no \"bench\": \"geometry\" lines in {', '.join(a.results)}")
    draw(rows, a.out)
    print(f"geometry_chart: wrote {a.out} ({len(rows)} lines)")


if __name__ == "__main__":
    main()
