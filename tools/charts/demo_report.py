#!/usr/bin/python3
"""The demo's report: reads what deploy/demo.sh's programs wrote (JSON with the json module, the
send/delta logs as whitespace-separated numbers) and writes report.json, report.md and
report.html beside them, with charts and a contact sheet (rendered | ground truth | error) as PNG
images they link.

    tools/charts/demo_report.py --out out/demo --frames 180 --store 50 [--wall_s 75]

Inputs under --out: upload.json (exoview_uploader --stats_json), upload_sends.txt
(--send_log: "timestamp_s steady_ns"), viewer_deltas.txt (exoview_viewer --delta_log:
"source_timestamp_s steady_ns bytes views"), viewer_state.json, frames/viewer_report.json (per-view
render ms and SSIM; PNGs of rendered views and ground truth), export/export.json (exoview_export).
"""
import argparse
import html
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.ticker  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

SET_LABEL = {
    "path": "on the input path",
    "near": "off the path, near it",
    "scene": "off the path, anywhere in the scene",
}
SET_COLOR = {"path": "#1f77b4", "near": "#ff7f0e", "scene": "#2ca02c"}


def load_json(path):
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def read_columns(path):
    rows = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            parts = line.split()
            if parts:
                rows.append([float(p) for p in parts])
    return rows


def stream_stats(out):
    """Frame-to-delta latency (first delta per source frame minus the frame's send time, both
    CLOCK_MONOTONIC on this host), bytes and rate received by the viewer."""
    sends = read_columns(os.path.join(out, "upload_sends.txt"))
    deltas = read_columns(os.path.join(out, "viewer_deltas.txt"))
    sent = {r[0]: r[1] for r in sends}
    seen, lat = set(), []  # (send time s since first send, latency ms)
    t0 = sends[0][1] if sends else 0.0
    for r in deltas:
        ts = r[0]
        if ts != 0 and ts in sent and ts not in seen:
            seen.add(ts)
            lat.append(((sent[ts] - t0) / 1e9, (r[1] - sent[ts]) / 1e6))
    total_bytes = sum(int(r[2]) for r in deltas)
    secs = (deltas[-1][1] - t0) / 1e9 if deltas and sends else 0.0
    ms = np.array([x[1] for x in lat]) if lat else np.array([])
    return {
        "frames_with_delta": len(lat),
        "frame_to_delta_p50_ms": float(np.percentile(ms, 50)) if ms.size else None,
        "frame_to_delta_p95_ms": float(np.percentile(ms, 95)) if ms.size else None,
        "viewer_bytes": total_bytes,
        "stream_seconds": secs,
        "viewer_kbit_per_s": total_bytes * 8 / 1000 / secs if secs > 0 else 0.0,
    }, lat, deltas, sends


def chart_ssim(per_frame, sets, path):
    fig, ax = plt.subplots(figsize=(8, 3.8), dpi=100)
    x = 0
    ticks, labels = [], []
    for name in [s for s in ("path", "near", "scene") if s in sets]:
        vals = [r["ssim"] for r in per_frame if r["set"] == name]
        xs = np.arange(x, x + len(vals))
        ax.bar(xs, vals, color=SET_COLOR[name], width=0.8)
        ax.hlines(sets[name]["mssim"], xs[0] - 0.4, xs[-1] + 0.4, colors="black", linewidth=1)
        ticks.append(xs.mean())
        labels.append(f"{SET_LABEL[name]}\n{len(vals)} views, MSSIM {sets[name]['mssim']:.3f}")
        x += len(vals) + 2
    ax.set_xticks(ticks, labels, fontsize=8)
    ax.set_ylim(0, 1)
    ax.set_yticks(np.arange(0, 1.01, 0.2))
    ax.set_ylabel("SSIM vs ground truth")
    ax.set_title("Novel views: SSIM per test view (black line: set mean)")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def chart_render_ms(per_frame, renderer, size, path):
    fig, ax = plt.subplots(figsize=(8, 3.2), dpi=100)
    for name in ("path", "near", "scene"):
        rows = [r for r in per_frame if r["set"] == name]
        if rows:
            ax.plot([r["index"] for r in rows], [r["render_ms"] for r in rows], "o-",
                    color=SET_COLOR[name], markersize=3, label=SET_LABEL[name])
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.set_xlabel("view index within its set (sets rendered in the legend's order)")
    ax.set_ylabel("render time (ms)")
    ax.set_ylim(bottom=0)
    ax.set_title(f"Render time per {size[0]}x{size[1]} view, {renderer.split(' (')[0]}")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def chart_stream(lat, delta_rows, sends, upload, store, path):
    """Three panels over the stream's time: frames sent vs views stored (the planner at work),
    frame-to-delta latency, bytes received by the viewer."""
    fig, (a0, a1, a2) = plt.subplots(1, 3, figsize=(12, 3.5), dpi=100)
    t0 = sends[0][1] if sends else 0.0
    if sends:
        a0.plot([(r[1] - t0) / 1e9 for r in sends], np.arange(1, len(sends) + 1),
                color="#7f7f7f", label="frames sent (uploader)")
    if delta_rows and len(delta_rows[0]) >= 4:
        a0.step([(r[1] - t0) / 1e9 for r in delta_rows], [r[3] for r in delta_rows], where="post",
                color="#1f77b4", label="views stored (viewer's copy)")
    a0.axhline(store, color="black", linestyle="--", linewidth=1, label=f"store capacity ({store})")
    a0.set_xlabel("time since the first frame was sent (s)")
    a0.set_ylabel("count")
    a0.set_ylim(bottom=0)
    a0.set_title("Frames streamed vs views kept")
    a0.legend(fontsize=8, loc="upper left")
    a0.grid(alpha=0.3)
    if lat:
        a1.plot([p[0] for p in lat], [p[1] for p in lat], ".", color="#1f77b4", markersize=4)
    a1.set_xlabel("time since the first frame was sent (s)")
    a1.set_ylabel("frame-to-delta latency (ms)")
    a1.set_ylim(bottom=0)
    a1.set_title("Frame sent -> first delta at the viewer")
    a1.grid(alpha=0.3)
    if delta_rows:
        a2.plot([(r[1] - t0) / 1e9 for r in delta_rows],
                np.cumsum([r[2] for r in delta_rows]) / 1e6, color="#2ca02c")
    a2.set_xlabel("time since the first frame was sent (s)")
    a2.set_ylabel("received by the viewer (MB)")
    a2.set_ylim(bottom=0)
    fps = upload.get("fps")
    a2.set_title(f"Delta stream (upload {fps:.1f} fps)" if fps else "Delta stream")
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def pick_contact_views(per_frame):
    """Per set: the view with the median SSIM and the worst one (the typical and the failure)."""
    picks = []
    for name in ("path", "near", "scene"):
        rows = sorted((r for r in per_frame if r["set"] == name and "png" in r and "gt_png" in r),
                      key=lambda r: r["ssim"])
        if not rows:
            continue
        median = rows[len(rows) // 2]
        picks.append(median)
        if rows[0] is not median:
            picks.append(rows[0])
    return picks


def contact_sheet(frames_dir, picks, path, dpi=100):
    rows = len(picks)
    fig, axes = plt.subplots(rows, 3, figsize=(9.6, 2.55 * rows), dpi=dpi, squeeze=False)
    for i, r in enumerate(picks):
        img = mpimg.imread(os.path.join(frames_dir, r["png"]))[..., :3]
        gt = mpimg.imread(os.path.join(frames_dir, r["gt_png"]))[..., :3]
        err = np.abs(img.astype(np.float64) - gt.astype(np.float64)).mean(axis=2) * 255.0
        axes[i][0].imshow(img)
        axes[i][1].imshow(gt)
        im = axes[i][2].imshow(err, cmap="inferno", vmin=0, vmax=64)
        axes[i][0].set_ylabel(f"{r['set']} #{r['index']}\nSSIM {r['ssim']:.3f}", fontsize=9)
        for a in axes[i]:
            a.set_xticks([])
            a.set_yticks([])
        cb = fig.colorbar(im, ax=axes[i][2], fraction=0.046, pad=0.02)
        cb.set_ticks([0, 16, 32, 48, 64])
        cb.ax.tick_params(labelsize=7)
    axes[0][0].set_title("rendered (lumigraph)", fontsize=10)
    axes[0][1].set_title("ground truth", fontsize=10)
    axes[0][2].set_title("|error| (8-bit levels, mean of RGB)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def r3(x):
    return None if x is None else round(float(x), 3)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="the demo's output folder")
    ap.add_argument("--frames", type=int, required=True, help="frames the uploader streamed")
    ap.add_argument("--store", type=int, required=True, help="the server's view store size")
    ap.add_argument("--wall_s", type=float, default=None, help="the demo's run time (s)")
    ap.add_argument("--docs_img", default=None,
                    help="also write screenshot-size copies for the docs here: "
                         "demo_contact_sheet.png (the median view of each set), demo_stream.png")
    a = ap.parse_args()
    out = a.out
    frames_dir = os.path.join(out, "frames")
    upload = load_json(os.path.join(out, "upload.json"))
    viewer = load_json(os.path.join(frames_dir, "viewer_report.json"))
    state = load_json(os.path.join(out, "viewer_state.json"))
    export = load_json(os.path.join(out, "export", "export.json"))
    rb_path = os.path.join(out, "export", "readback.json")
    readback = load_json(rb_path) if os.path.exists(rb_path) else None
    stream, lat, delta_rows, sends = stream_stats(out)
    sets = viewer.get("sets", {})
    per_frame = viewer.get("per_frame", [])
    if "path" not in sets:
        sys.exit("demo_report: the viewer rendered no views on the path")

    charts = {"ssim": "chart_ssim.png", "render_ms": "chart_render_ms.png",
              "stream": "chart_stream.png", "contact_sheet": "contact_sheet.png"}
    chart_ssim(per_frame, sets, os.path.join(out, charts["ssim"]))
    chart_render_ms(per_frame, viewer["renderer"], (viewer["width"], viewer["height"]),
                    os.path.join(out, charts["render_ms"]))
    chart_stream(lat, delta_rows, sends, upload, a.store, os.path.join(out, charts["stream"]))
    picks = pick_contact_views(per_frame)
    contact_sheet(frames_dir, picks, os.path.join(out, charts["contact_sheet"]))
    if a.docs_img:
        os.makedirs(a.docs_img, exist_ok=True)
        medians = [p for i, p in enumerate(picks)
                   if i == 0 or p["set"] != picks[i - 1]["set"]]  # first pick per set = median
        contact_sheet(frames_dir, medians, os.path.join(a.docs_img, "demo_contact_sheet.png"), dpi=80)
        chart_stream(lat, delta_rows, sends, upload, a.store,
                     os.path.join(a.docs_img, "demo_stream.png"))

    report = {
        "scene": "apartment/walk",
        "frames_streamed": a.frames,
        "frames_accepted_by_server": state.get("server_frames_accepted"),
        "store_capacity_views": a.store,
        "views_stored": state["views"],
        "upload": upload,
        "renderer": viewer["renderer"],
        "render_size": [viewer["width"], viewer["height"]],
        "sets": {k: {"views": v["views"], "mssim": r3(v["mssim"]),
                     "mean_render_ms": round(v["mean_render_ms"], 1)} for k, v in sets.items()},
        "stream": {k: (r3(v) if isinstance(v, float) else v) for k, v in stream.items()},
        "viewer_store": state,
        "export": export,
        "export_readback": readback,
        "images": charts,
        "contact_sheet_views": [{"set": r["set"], "index": r["index"], "ssim": r3(r["ssim"])}
                                for r in picks],
        "demo_wall_s": round(a.wall_s, 1) if a.wall_s is not None else None,
    }
    with open(os.path.join(out, "report.json"), "w", encoding="utf-8") as f:
        json.dump(report, f, indent=1)
        f.write("\n")

    def fmt(x, digits=1):
        return "n/a" if x is None else f"{x:.{digits}f}"

    rows = [
        ("frames streamed (640x480 RGB-D, asked 30 Hz) / accepted by the server (frames)",
         f"{a.frames} at {fmt(upload.get('fps'))} fps / {state.get('server_frames_accepted', 'n/a')}"),
        ("views stored (store capacity)", f"{state['views']} ({a.store})"),
    ]
    for k in ("path", "near", "scene"):
        if k in sets:
            rows.append((f"MSSIM, {sets[k]['views']} views {SET_LABEL[k]}",
                         f"{sets[k]['mssim']:.3f}"))
    rows += [
        (f"renderer, mean render time per {viewer['width']}x{viewer['height']} view on the path",
         f"{viewer['renderer']}, {sets['path']['mean_render_ms']:.1f} ms"),
        ("bytes received by the viewer",
         f"{stream['viewer_bytes'] / 1e6:.1f} MB ({stream['viewer_kbit_per_s'] / 1000:.1f} Mbit/s "
         f"over {stream['stream_seconds']:.1f} s)"),
        ("frame-to-delta latency p50 / p95",
         f"{fmt(stream['frame_to_delta_p50_ms'], 0)} / {fmt(stream['frame_to_delta_p95_ms'], 0)} ms "
         f"({stream['frames_with_delta']} frames produced deltas)"),
        ("upload ack latency p50 / p95",
         f"{fmt(upload.get('ack_latency_p50_ms'))} / {fmt(upload.get('ack_latency_p95_ms'))} ms"),
        ("export of the viewer's store",
         f"{export['mesh_vertices']} vertices / {export['mesh_triangles']} triangles, "
         f"{export['views']} poses"),
    ]
    if readback:
        rows.append(("export read back (tools/export/read_exports.py)",
                     f"{readback['vertices']} vertices / {readback['faces']} faces, normals unit to "
                     f"{readback['normal_max_error']:.0e}, {readback['views']} TUM = COLMAP poses; "
                     + (f"Open3D {readback['open3d']} agrees" if readback.get("open3d")
                        else "Open3D not installed")))
    if a.wall_s is not None:
        rows.append(("demo run time", f"{a.wall_s:.0f} s"))
    exported = [f for f in export["files"] if not f.startswith("colmap/images/")]
    n_images = len(export["files"]) - len(exported)

    md = ["# Exoview demo (synthetic apartment walk, server + uploader + viewer over gRPC on loopback)",
          "",
          f"The uploader streams {a.frames} frames into a server whose view store holds "
          f"{a.store} views, so the view planner chooses which frames to keep "
          f"({state['views']} stored). The viewer renders novel views on the input path and off "
          "it, and compares each with the synthetic scene's ground truth.",
          "", "| what | value |", "|---|---|"]
    md += [f"| {k} | {v} |" for k, v in rows]
    md += ["", "## Charts", "",
           f"![SSIM per test view]({charts['ssim']})", "",
           f"![render time per view]({charts['render_ms']})", "",
           f"![latency and delta stream]({charts['stream']})", "",
           "## Contact sheet (per set: the median-SSIM view and the worst)", "",
           f"![rendered, ground truth, error]({charts['contact_sheet']})", "",
           "## Files", "",
           "- frames: `frames/frame_*.png` (path), `frames/near_*.png`, `frames/scene_*.png`, "
           "ground truth `*_gt.png`, `frames/frames.mjpeg`; per-view ms and SSIM: "
           "`frames/viewer_report.json`",
           "- the viewer's store: `viewer.model`; upload ack statistics: `upload.json`",
           "- exports (`exoview_export --model viewer.model --out export`): "
           + ", ".join(f"`export/{f}`" for f in exported)
           + f", {n_images} images in `export/colmap/images/`, summary `export/export.json`",
           "- synthetic scenes: `synth/`", ""]
    with open(os.path.join(out, "report.md"), "w", encoding="utf-8") as f:
        f.write("\n".join(md))

    h = ["<!doctype html><meta charset='utf-8'><title>Exoview demo</title>",
         "<style>body{font-family:sans-serif;max-width:1000px;margin:2em auto}"
         "td,th{border:1px solid #ccc;padding:4px 8px}table{border-collapse:collapse}</style>",
         "<h1>Exoview demo</h1>", f"<p>{html.escape(md[2])}</p>", "<table>"]
    h += [f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows]
    h += ["</table>"]
    for key in ("ssim", "render_ms", "stream", "contact_sheet"):
        h.append(f"<p><img src='{charts[key]}' style='max-width:100%'></p>")
    h.append("<h2>Exported files</h2><ul>")
    h += [f"<li><a href='export/{html.escape(f)}'>export/{html.escape(f)}</a></li>" for f in exported]
    h.append(f"<li>{n_images} images in export/colmap/images/</li></ul>")
    with open(os.path.join(out, "report.html"), "w", encoding="utf-8") as f:
        f.write("\n".join(h) + "\n")


if __name__ == "__main__":
    main()
