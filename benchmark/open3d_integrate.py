#!/usr/bin/python3
"""Open3D 0.16 ScalableTSDFVolume on the same 7-Scenes frames geometry_bench integrates.

Frames 0..N-1 of a 7-Scenes folder, every 10th held out (not integrated), as geometry_bench does.
Depth: the raw 16-bit PNG (mm, depth_scale 1000) with the data's depth K, not registered to
colour (geometry_bench's SevenScenesReader default); colour: the JPG as is (RGB8). Camera pose:
frame-*.pose.txt (camera-to-world; Open3D takes its inverse). Same voxel, sdf_trunc = 4 voxels
(TsdfOptions' default truncation), depth_trunc = 4.0 m (geometry_bench's max_depth_m).
Only `volume.integrate(...)` is timed (wall and process CPU); images are decoded before.
Run with OMP_NUM_THREADS=1 for the single-thread figure. Prints one JSON line per voxel size.
"""
import argparse
import json
import os
import statistics
import sys
import time

import numpy as np
import open3d as o3d


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="7-Scenes folder")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--voxels", default="0.01,0.02,0.04", help="voxel sizes in m")
    ap.add_argument("--trunc_voxels", type=float, default=4.0)
    ap.add_argument("--depth_trunc", type=float, default=4.0)
    args = ap.parse_args()
    k = np.loadtxt(os.path.join(args.data, "camera-intrinsics.txt"))
    if k.shape != (3, 3):
        sys.exit(f"bad camera-intrinsics.txt in {args.data}")
    frames = []
    for i in range(args.frames):
        if i % 10 == 0:
            continue  # held out, as in geometry_bench
        stem = os.path.join(args.data, f"frame-{i:06d}")
        if not os.path.exists(stem + ".depth.png"):
            break
        color = o3d.io.read_image(stem + ".color.jpg")
        depth = o3d.io.read_image(stem + ".depth.png")
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, depth, depth_scale=1000.0, depth_trunc=args.depth_trunc,
            convert_rgb_to_intensity=False)
        world_from_cam = np.loadtxt(stem + ".pose.txt")
        frames.append((rgbd, np.linalg.inv(world_from_cam)))
    if not frames:
        sys.exit(f"no frames in {args.data}")
    h, w = np.asarray(frames[0][0].depth).shape
    intr = o3d.camera.PinholeCameraIntrinsic(w, h, k[0, 0], k[1, 1], k[0, 2], k[1, 2])
    for voxel in [float(v) for v in args.voxels.split(",")]:
        vol = o3d.pipelines.integration.ScalableTSDFVolume(
            voxel_length=voxel, sdf_trunc=args.trunc_voxels * voxel,
            color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8)
        wall, cpu = [], []
        for rgbd, extrinsic in frames:
            c0, t0 = time.process_time(), time.perf_counter()
            vol.integrate(rgbd, intr, extrinsic)
            wall.append((time.perf_counter() - t0) * 1e3)
            cpu.append((time.process_time() - c0) * 1e3)
        t0 = time.perf_counter()
        mesh = vol.extract_triangle_mesh()
        extract_ms = (time.perf_counter() - t0) * 1e3
        print(json.dumps({
            "bench": "open3d_integrate", "open3d": o3d.__version__, "frames": len(frames),
            "voxel_m": voxel, "sdf_trunc_m": args.trunc_voxels * voxel,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS", ""),
            "integrate_ms_median": round(statistics.median(wall), 2),
            "integrate_cpu_ms_median": round(statistics.median(cpu), 2),
            "extract_all_ms": round(extract_ms, 1),
            "triangles": len(mesh.triangles)}), flush=True)


if __name__ == "__main__":
    main()
