#!/usr/bin/python3
"""Server memory over a long upload (docs/service.md "Memory over a long session") from
service_bench's JSON lines (--rss_frames), with matplotlib.

    tools/charts/rss_chart.py LABEL=RESULTS.jsonl [LABEL=MORE.jsonl ...] --out docs/img/service_rss.png
        [--flat_from 5000] [--band 0.02]

Reads every "rss_sample" line (frames, rss_mb, heap_in_use_mb, heap_free_mb) of each file and
draws, one colour per file: server RSS (solid) against frames sent with the +-band around the RSS
at frame --flat_from shaded, and the glibc heap's live (dashed) and free (dotted) MB. Prints, per
file, the RSS at --flat_from, the last, and the largest deviation from it after --flat_from.
Exits 1 without data.
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from jsonl import read_jsonl  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#7f7f7f"]


def load(path):
    rows = [d for _, _, d in read_jsonl([path], "rss_chart") if d.get("phase") == "rss_sample"]
    return sorted(rows, key=lambda d: d["frames"])


def flatness(rows, flat_from):
    """(RSS at the first sample >= flat_from, last RSS, largest |deviation| after it as a
    fraction), or None when no sample reaches flat_from."""
    after = [d for d in rows if d["frames"] >= flat_from]
    if not after:
        return None
    ref = after[0]["rss_mb"]
    dev = max(abs(d["rss_mb"] - ref) for d in after) / ref
    return ref, after[-1]["rss_mb"], dev


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("inputs", nargs="+", help="LABEL=FILE.jsonl")
    ap.add_argument("--out", required=True)
    ap.add_argument("--flat_from", type=int, default=5000)
    ap.add_argument("--band", type=float, default=0.02)
    a = ap.parse_args()
    series = []
    for arg in a.inputs:
        label, sep, path = arg.rpartition("=")  # the label may hold "="
        if not sep:
            label, path = os.path.basename(arg), arg
        rows = load(path)
        if rows:
            series.append((label, rows))
    if not series:
        print("rss_chart: no rss_sample lines", file=sys.stderr)
        return 1
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.4), dpi=100)
    for i, (label, rows) in enumerate(series):
        c = COLORS[i % len(COLORS)]
        x = [d["frames"] for d in rows]
        ax1.plot(x, [d["rss_mb"] for d in rows], "-o", ms=3, color=c, label=label)
        f = flatness(rows, a.flat_from)
        if f:
            ref, last, dev = f
            ax1.axhspan(ref * (1 - a.band), ref * (1 + a.band), color=c, alpha=0.12)
            print(f"{label}: RSS {ref} MB at frame >= {a.flat_from}, {last} MB at the end, "
                  f"max deviation {100 * dev:.1f} %")
        if all("heap_in_use_mb" in d for d in rows):
            ax2.plot(x, [d["heap_in_use_mb"] for d in rows], "--", color=c, label=f"{label}: live")
            ax2.plot(x, [d["heap_free_mb"] for d in rows], ":", color=c, lw=2,
                     label=f"{label}: free in arenas")
    ax1.set_title(f"server RSS (band: +-{100 * a.band:.0f} % of frame {a.flat_from})", fontsize=11)
    ax2.set_title("glibc heap (mallinfo2)", fontsize=11)
    for ax in (ax1, ax2):
        ax.set_xlabel("frames sent (unpaced)")
        ax.set_ylabel("MB")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out)
    print(f"rss_chart: wrote {a.out} ({sum(len(r) for _, r in series)} samples)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
