#!/usr/bin/python3
"""Our TSDF integration beside Open3D 0.16's ScalableTSDFVolume on the same 7-Scenes frames.

Interleaves, per repeat: geometry_bench (ours, single thread, per-pixel allocation stride 1 and
the default subsampled stride, integration only) and benchmark/open3d_integrate.py
(OMP_NUM_THREADS=1). Prints one JSON line per voxel size with per-frame integrate CPU and wall
ms (median over frames, then median over repeats) and the ratio ours / Open3D (< 1: ours faster).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def run_lines(cmd, env=None):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
    return [json.loads(l) for l in out.splitlines() if l.startswith("{")]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bench", default=os.path.join(HERE, "..", "build", "server", "geometry",
                                                    "geometry_bench"))
    ap.add_argument("--data", default=os.path.join(HERE, "..", "..", "shared", "data",
                                                   "7scenes-redkitchen"))
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--voxels", default="0.01,0.02,0.04")
    ap.add_argument("--strides", default="1,4", help="our alloc_stride values")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--python", default="/usr/bin/python3",
                    help="interpreter with open3d (Debian python3-open3d)")
    args = ap.parse_args()
    if not os.path.exists(os.path.join(args.data, "camera-intrinsics.txt")):
        sys.exit(f"no 7-Scenes data at {args.data}")
    strides = [int(s) for s in args.strides.split(",")]
    ours, o3d = {}, {}  # (voxel, stride) / voxel -> list of (cpu, wall)
    env1 = dict(os.environ, OMP_NUM_THREADS="1")
    for rep in range(args.repeats):
        for r in run_lines([args.bench, "--synth_frames", "0", "--frames", str(args.frames),
                            "--data", args.data, "--voxels", args.voxels, "--alloc_strides",
                            args.strides, "--threads", "1", "--extract_every_frame", "false"]):
            ours.setdefault((r["voxel_m"], r["alloc_stride"]), []).append(
                (r["integrate_cpu_ms_median"], r["integrate_ms_median"], r["triangles"]))
        for r in run_lines([args.python, os.path.join(HERE, "open3d_integrate.py"), "--data",
                            args.data, "--frames", str(args.frames), "--voxels", args.voxels],
                           env=env1):
            o3d.setdefault(r["voxel_m"], []).append(
                (r["integrate_cpu_ms_median"], r["integrate_ms_median"], r["triangles"]))
    med = lambda xs, i: round(statistics.median(x[i] for x in xs), 2)
    for v in sorted(o3d):
        line = {"bench": "fusion_vs_open3d", "voxel_m": v, "frames_integrated": None,
                "repeats": args.repeats, "threads": 1,
                "open3d_cpu_ms": med(o3d[v], 0), "open3d_wall_ms": med(o3d[v], 1),
                "open3d_triangles": o3d[v][0][2]}
        for s in strides:
            if (v, s) not in ours:
                continue
            line[f"ours_stride{s}_cpu_ms"] = med(ours[(v, s)], 0)
            line[f"ours_stride{s}_wall_ms"] = med(ours[(v, s)], 1)
            line[f"ours_stride{s}_triangles"] = ours[(v, s)][0][2]
            line[f"ratio_cpu_stride{s}_over_open3d"] = round(
                med(ours[(v, s)], 0) / med(o3d[v], 0), 2)
        line["frames_integrated"] = args.frames - (args.frames + 9) // 10
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
