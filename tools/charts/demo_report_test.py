#!/usr/bin/python3
"""Tests of demo_report.py on inputs written here (the files deploy/demo.sh's programs write):
latency percentiles from the send/delta logs, MSSIM per set, the contact sheet's picks, and the
report files with the images they link."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import matplotlib.image as mpimg
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import demo_report as dr  # noqa: E402


def read_json(path):
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def read_text(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def write_inputs(d):
    os.makedirs(os.path.join(d, "frames"))
    os.makedirs(os.path.join(d, "export"))
    with open(os.path.join(d, "upload.json"), "w") as f:
        json.dump({"sent": 10, "accepted": 10, "rejected": 0, "fps": 29.5,
                   "ack_latency_p50_ms": 3.25, "ack_latency_p95_ms": 9.5}, f)
    # 10 frames sent 100 ms apart; frame i's first delta arrives (10 + 10 i) ms later, a second
    # delta of the same frame later still (must not count), and one delta without a source frame
    # (source timestamp 0: publisher housekeeping, not counted).
    with open(os.path.join(d, "upload_sends.txt"), "w") as f:
        for i in range(10):
            f.write(f"{(i + 1) / 30} {1_000_000_000 + i * 100_000_000}\n")
    with open(os.path.join(d, "viewer_deltas.txt"), "w") as f:
        f.write(f"0 {1_000_000_000} 100 0\n")
        for i in range(10):
            t = 1_000_000_000 + i * 100_000_000 + (10 + 10 * i) * 1_000_000
            f.write(f"{(i + 1) / 30} {t} 1000 {min(i + 1, 4)}\n")
            f.write(f"{(i + 1) / 30} {t + 5_000_000} 500 {min(i + 1, 4)}\n")
    with open(os.path.join(d, "viewer_state.json"), "w") as f:
        json.dump({"version": 20, "views": 4, "server_frames_accepted": 10}, f)
    rng = np.random.default_rng(1)
    per_frame, sets = [], {}
    for name, n, base in (("path", 4, 0.9), ("near", 3, 0.8), ("scene", 3, 0.6)):
        ssims = [base + 0.01 * k for k in range(n)]
        for k, s in enumerate(ssims):
            img = rng.random((24, 32, 3))
            mpimg.imsave(os.path.join(d, "frames", f"{name}_{k}.png"), img)
            mpimg.imsave(os.path.join(d, "frames", f"{name}_{k}_gt.png"), np.clip(img + 0.1, 0, 1))
            per_frame.append({"set": name, "index": k, "render_ms": 10.0 + k, "ssim": s,
                              "png": f"{name}_{k}.png", "gt_png": f"{name}_{k}_gt.png"})
        sets[name] = {"views": n, "mssim": float(np.mean(ssims)), "mean_render_ms": 11.0}
    with open(os.path.join(d, "frames", "viewer_report.json"), "w") as f:
        json.dump({"renderer": "cpu", "width": 32, "height": 24, "sets": sets,
                   "per_frame": per_frame}, f)
    with open(os.path.join(d, "export", "export.json"), "w") as f:
        json.dump({"mesh_vertices": 5, "mesh_triangles": 3, "views": 4,
                   "files": ["mesh.ply", "trajectory.tum", "colmap/images/view_000001.jpg"]}, f)
    with open(os.path.join(d, "export", "readback.json"), "w") as f:
        json.dump({"vertices": 5, "faces": 3, "normal_max_error": 2e-8, "views": 4,
                   "open3d": "0.16.1"}, f)


class DemoReportTest(unittest.TestCase):
    def test_report_numbers_and_images(self):
        with tempfile.TemporaryDirectory() as d:
            write_inputs(d)
            subprocess.run([sys.executable, os.path.join(HERE, "demo_report.py"), "--out", d,
                            "--frames", "10", "--store", "4", "--wall_s", "61.4"], check=True)
            r = read_json(os.path.join(d, "report.json"))
            self.assertEqual(r["frames_streamed"], 10)
            self.assertEqual(r["views_stored"], 4)
            self.assertEqual(r["store_capacity_views"], 4)
            s = r["stream"]
            self.assertEqual(s["frames_with_delta"], 10)
            self.assertAlmostEqual(s["frame_to_delta_p50_ms"], 55.0, places=3)  # 10..100 ms
            self.assertAlmostEqual(s["frame_to_delta_p95_ms"], 95.5, places=3)
            self.assertEqual(s["viewer_bytes"], 100 + 10 * 1500)
            self.assertEqual(r["sets"]["near"]["mssim"], 0.81)
            self.assertEqual(r["demo_wall_s"], 61.4)
            # Contact sheet: median and worst per set.
            picks = [(p["set"], p["index"]) for p in r["contact_sheet_views"]]
            self.assertEqual(picks, [("path", 2), ("path", 0), ("near", 1), ("near", 0),
                                     ("scene", 1), ("scene", 0)])
            md, html = read_text(os.path.join(d, "report.md")), read_text(os.path.join(d, "report.html"))
            for png in r["images"].values():
                self.assertIn(f"({png})", md)
                self.assertIn(png, html)
                img = mpimg.imread(os.path.join(d, png))
                self.assertGreater(img.shape[0], 200)
                self.assertGreater(img.std(), 0.01)
            self.assertIn("| views stored (store capacity) | 4 (4) |", md)
            self.assertIn("`export/mesh.ply`", md)
            self.assertIn("5 vertices / 3 faces, normals unit to 2e-08, 4 TUM = COLMAP poses; "
                          "Open3D 0.16.1 agrees", md)

    def test_missing_path_set_is_an_error(self):
        with tempfile.TemporaryDirectory() as d:
            write_inputs(d)
            p = os.path.join(d, "frames", "viewer_report.json")
            rep = read_json(p)
            del rep["sets"]["path"]
            with open(p, "w") as f:
                json.dump(rep, f)
            res = subprocess.run([sys.executable, os.path.join(HERE, "demo_report.py"), "--out", d,
                                  "--frames", "10", "--store", "4"], capture_output=True, text=True)
            self.assertNotEqual(res.returncode, 0)
            self.assertIn("no views on the path", res.stderr)


if __name__ == "__main__":
    unittest.main()
