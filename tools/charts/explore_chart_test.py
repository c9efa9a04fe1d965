#!/usr/bin/python3
"""Tests of explore_chart.py: only summary lines are read (the last per (scene, policy) wins),
the PNG is an image of the expected size, and input without summaries is an error."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import matplotlib.image as mpimg

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import explore_chart as ec  # noqa: E402

SCRIPT = os.path.join(HERE, "explore_chart.py")


def summary(scene, policy, scale, mssim=True):
    d = {"bench": "explore", "scene": scene, "policy": policy, "runs": 3,
         "metric": {"cell_m": 0.5, "d_max_m": 2.0, "sigma_m": 2.0},
         "mean_coverage_at_s": {str(t): min(0.95, scale * t / 360) for t in range(30, 361, 30)}}
    if mssim:
        d["mean_mssim_at_s"] = {str(t): 0.4 + 0.3 * scale * t / 360 for t in range(60, 361, 60)}
        d["test_views"] = 12
        d["store"] = 100
    return d


class ExploreChartTest(unittest.TestCase):
    def write(self, d, lines):
        src = os.path.join(d, "e.jsonl")
        with open(src, "w") as f:
            f.write("\n".join(json.dumps(x) for x in lines) + "\n")
        return src

    def test_reads_summaries_last_line_wins(self):
        with tempfile.TemporaryDirectory() as d:
            src = self.write(d, [{"bench": "explore_run", "scene": "apartment", "policy": "x"},
                                 summary("apartment", "autonomous", 0.5),
                                 summary("apartment", "autonomous", 0.9),
                                 summary("village", "scripted", 0.3)])
            rows = ec.load([src])
            self.assertEqual(len(rows), 2)
            self.assertAlmostEqual(rows[("apartment", "autonomous")]["mean_coverage_at_s"]["360"],
                                   0.9)
            pts = ec.series(rows[("apartment", "autonomous")], "mean_coverage_at_s", 0.0)
            self.assertEqual(pts[0], (0.0, 0.0))
            self.assertEqual(pts[-1][0], 360.0)

    def test_writes_a_png_of_the_expected_size(self):
        lines = [summary(s, p, k) for s in ("apartment", "village")
                 for p, k in (("autonomous", 1.0), ("frontier", 0.3), ("scripted", 0.6))]
        lines.append(summary("village", "frontier", 0.2, mssim=False))
        with tempfile.TemporaryDirectory() as d:
            src = self.write(d, lines)
            png = os.path.join(d, "t.png")
            out = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                                 capture_output=True, text=True, check=True).stdout
            self.assertIn("apartment, village", out)
            img = mpimg.imread(png)
            self.assertEqual(img.shape[:2], (720, 1100))

    def test_no_summary_is_an_error(self):
        with tempfile.TemporaryDirectory() as d:
            src = self.write(d, [{"bench": "explore_run", "scene": "apartment"}])
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", os.path.join(d, "x.png")],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 1)
            self.assertIn("no 'explore' summary lines", r.stderr)
            self.assertFalse(os.path.exists(os.path.join(d, "x.png")))


if __name__ == "__main__":
    unittest.main()
