#!/usr/bin/python3
"""Time-vs-error chart of keyframe inpainting (docs/inpainting.md) from inpaint_bench's JSON lines, with matplotlib.

    tools/charts/inpaint_chart.py RESULTS.jsonl [MORE.jsonl ...] --out docs/img/inpaint_time_vs_error.png

Reads the per-(method, class) summary lines ("bench": "inpaint_summary"; per-mask lines and the
run_info line are skipped; the run_info's nproc/cpu go into the subtitle when present) and draws
the wall time per keyframe (ms_p50, log scale) against the mean depth MAE in the mask
(depth_mae_mm), one colour per method, one marker size per mask class, the classes of a method
joined by a thin line. Lines from several files are drawn together (the last line of a
(method, class) wins). Exits 1 without data.
"""
import argparse
import os
import math
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from jsonl import read_jsonl  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, NullLocator  # noqa: E402

# inpaint_bench's method names: (legend name, colour), in legend order.
METHODS = {
    "inpaintfusion": ("InpaintFusion (ours)", "#d62728"),
    "inpaintfusion_depth_domain": ("ours, depth domain (thesis)", "#ff7f0e"),
    "patchmatch_colour_only": ("colour-only PatchMatch", "#1f77b4"),
    "telea": ("Telea (colour + depth)", "#2ca02c"),
    "plane_ring": ("plane through ring", "#9467bd"),
    "inpaintfusion_propagated": ("ours, propagated (+5)", "#8c1a1a"),
    "inpaintfusion_scratch_next": ("ours, +5 from scratch", "#7f7f7f"),
}
CLASSES = {"2-5%": 30, "10-20%": 80, "30-40%": 160}  # marker area (points^2)


def load(paths):
    rows, info = {}, None
    for p, n, d in read_jsonl(paths, "inpaint_chart"):
        if "run_info" in d and info is None:
            info = d["run_info"]
        if d.get("bench") != "inpaint_summary":
            continue
        for k in ("method", "class", "ms_p50", "depth_mae_mm"):
            if k not in d:
                sys.exit(f"inpaint_chart: {p}:{n}: summary line without \"{k}\"")
        rows[(d["method"], d["class"])] = d
    return list(rows.values()), info


def finite(x):
    return isinstance(x, (int, float)) and math.isfinite(x)


def draw(rows, info, path):
    fig, ax = plt.subplots(figsize=(8.6, 5.0), dpi=100)
    order = list(METHODS) + sorted({r["method"] for r in rows} - set(METHODS))
    drawn = []
    for i, method in enumerate(order):
        pts = [r for r in rows if r["method"] == method and finite(r["depth_mae_mm"])
               and finite(r["ms_p50"]) and r["ms_p50"] > 0]
        if not pts:
            continue
        name, color = METHODS.get(method, (method, f"C{i % 10}"))
        pts.sort(key=lambda r: list(CLASSES).index(r["class"]) if r["class"] in CLASSES else 99)
        if len(pts) > 1:
            ax.plot([r["ms_p50"] for r in pts], [r["depth_mae_mm"] for r in pts], "-", color=color,
                    lw=0.8, alpha=0.5)
        ax.scatter([r["ms_p50"] for r in pts], [r["depth_mae_mm"] for r in pts],
                   s=[CLASSES.get(r["class"], 50) for r in pts], facecolors="none",
                   edgecolors=color, linewidths=1.8, zorder=3)
        drawn.append(Line2D([], [], marker="o", ls="-", lw=0.8, color=color, mfc="none", mew=1.8,
                            label=name))
    if not drawn:
        plt.close(fig)
        return False
    ax.set_xscale("log")
    ms_min = min(r["ms_p50"] for r in rows if finite(r["ms_p50"]) and r["ms_p50"] > 0)
    ax.set_xlim(left=10 ** math.floor(math.log10(0.8 * ms_min)))  # start at a labelled decade
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    ax.xaxis.set_minor_formatter(FuncFormatter(
        lambda x, _: f"{x:g}" if f"{x:.1e}"[0] in "25" else ""))
    ax.tick_params(axis="x", which="minor", labelsize=7)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3, which="both")
    threads = sorted({r.get("threads") for r in rows if r.get("threads")})
    th = f", {'/'.join(map(str, threads))} threads" if threads else ""
    ax.set_xlabel(f"wall time per keyframe, p50 (ms, log scale; 640×480{th})")
    ax.set_ylabel("depth MAE in the mask (mm, mean over masks)")
    title = "Keyframe inpainting: time vs depth error (7-Scenes redkitchen, registered)"
    if info:
        sub = ", ".join(str(info[k]) for k in ("commit", "cpu_model") if info.get(k))
        if info.get("nproc"):
            sub += f", {info['nproc']} cores"
        load = info.get("loadavg")
        if isinstance(load, list) and load:
            sub += f", load {load[0]:.1f}"
        if info.get("time_utc"):
            sub += f", {info['time_utc']}"
        title += f"\n{sub}"
    ax.set_title(title, fontsize=10)
    sizes = [Line2D([], [], marker="o", ls="", color="black", mfc="none",
                    markersize=math.sqrt(a), label=f"mask {c}") for c, a in CLASSES.items()]
    ax.legend(handles=drawn + sizes, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0, labelspacing=1.0)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", nargs="+", help="JSON-lines files of inpaint_bench")
    ap.add_argument("--out", required=True, help="PNG to write")
    a = ap.parse_args()
    rows, info = load(a.results)
    if not draw(rows, info, a.out):
        sys.exit(f"inpaint_chart: no \"inpaint_summary\" lines with a depth MAE in "
                 f"{', '.join(a.results)}")
    print(f"inpaint_chart: wrote {a.out} ({len(rows)} summary lines)")


if __name__ == "__main__":
    main()
