#!/usr/bin/python3
"""Tests of geometry_chart.py: repeats are averaged per (dataset, stride, voxel), the PNG is an
image of the expected size, and input without geometry lines or with bad lines is an error."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import matplotlib.image as mpimg

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import geometry_chart as gc  # noqa: E402

SCRIPT = os.path.join(HERE, "geometry_chart.py")


def line(dataset, voxel, rep=0, stride=8, ms=10.0):
    err = ("vertex_err_mm_mean" if dataset == "synthetic-room" else "heldout_abs_sdf_mm_mean")
    return {"bench": "geometry", "dataset": dataset, "frames": 12, "voxel_m": voxel,
            "alloc_stride": stride, "repeat": rep, "integrate_ms_median": ms,
            "extract_dirty_ms_median": ms / 2, "triangles": int(3e4 / voxel ** 2 / 1e4),
            err: 100 * voxel, "coverage": 1.0 if dataset == "synthetic-room" else 0.95}


class GeometryChartTest(unittest.TestCase):
    def test_series_average_repeats_and_sort_by_voxel(self):
        rows = [line("synthetic-room", 0.04, 0, ms=10), line("synthetic-room", 0.04, 1, ms=20),
                line("synthetic-room", 0.01, 0, ms=50), line("synthetic-room", 0.01, 0, stride=1)]
        s = gc.series(rows)
        self.assertEqual(sorted(s), [("synthetic-room", 1), ("synthetic-room", 8)])
        pts = s[("synthetic-room", 8)]
        self.assertEqual([v for v, _ in pts], [0.01, 0.04])
        self.assertAlmostEqual(pts[1][1]["integrate_ms_median"], 15.0)
        self.assertAlmostEqual(pts[0][1]["integrate_ms_median"], 50.0)

    def test_writes_a_png_of_the_expected_size(self):
        rows = [line(ds, v, r) for ds in ("synthetic-room", "7scenes-redkitchen")
                for v in (0.01, 0.02, 0.04, 0.08) for r in (0, 1)]
        with tempfile.TemporaryDirectory() as d:
            src, png = os.path.join(d, "g.jsonl"), os.path.join(d, "sub", "g.png")
            os.makedirs(os.path.dirname(png))
            with open(src, "w") as f:
                f.write(json.dumps({"bench": "run_info", "run_info": {"commit": "abc"}}) + "\n")
                f.write("\n".join(json.dumps(r) for r in rows) + "\n\n")
            out = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                                 capture_output=True, text=True, check=True).stdout
            self.assertIn("16 lines", out)
            img = mpimg.imread(png)
            self.assertEqual(img.shape[:2], (440, 1350))
            self.assertGreater(img.std(), 0.01)  # not a blank canvas

    def test_no_data_or_bad_lines_are_errors(self):
        with tempfile.TemporaryDirectory() as d:
            src, png = os.path.join(d, "g.jsonl"), os.path.join(d, "g.png")
            with open(src, "w") as f:
                f.write(json.dumps({"bench": "eval"}) + "\n")
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                               capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("no \"bench\": \"geometry\" lines", r.stderr)
            with open(src, "w") as f:
                f.write(json.dumps({"bench": "geometry", "dataset": "x", "voxel_m": 0.02}) + "\n")
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                               capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("g.jsonl:1", r.stderr)
            self.assertIn("integrate_ms_median", r.stderr)
            with open(src, "w") as f:
                f.write(json.dumps(line("synthetic-room", 0.02)) + "\n{not json\n")
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                               capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("g.jsonl:2", r.stderr)
            self.assertFalse(os.path.exists(png))


if __name__ == "__main__":
    unittest.main()
