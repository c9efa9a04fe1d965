#!/usr/bin/python3
"""Tests of inpaint_chart.py: only summary lines are read (the last per (method, class) wins),
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
import inpaint_chart as ic  # noqa: E402

SCRIPT = os.path.join(HERE, "inpaint_chart.py")


def summary(method, cls, ms, mae):
    return {"bench": "inpaint_summary", "method": method, "class": cls, "runs": 10, "threads": 2,
            "ms_p50": ms, "ms_p95": 2 * ms, "psnr": 15.0, "depth_mae_mm": mae}


class InpaintChartTest(unittest.TestCase):
    def write(self, d, lines):
        src = os.path.join(d, "i.jsonl")
        with open(src, "w") as f:
            f.write("\n".join(json.dumps(x) for x in lines) + "\n")
        return src

    def test_reads_summaries_last_line_wins(self):
        with tempfile.TemporaryDirectory() as d:
            src = self.write(d, [
                {"bench": "inpaint", "run_info": {"commit": "abc", "nproc": 2}},
                {"bench": "inpaint", "method": "telea", "class": "2-5%", "ms": 3.0},
                summary("telea", "2-5%", 30, 100.0), summary("telea", "2-5%", 40, 110.0),
                summary("inpaintfusion", "2-5%", 90, 72.0)])
            rows, info = ic.load([src])
            self.assertEqual(info["commit"], "abc")
            by = {(r["method"], r["class"]): r for r in rows}
            self.assertEqual(len(by), 2)
            self.assertEqual(by[("telea", "2-5%")]["depth_mae_mm"], 110.0)

    def test_writes_a_png_of_the_expected_size(self):
        lines = [{"bench": "inpaint", "run_info": {"commit": "abc", "nproc": 2,
                                                   "cpu_model": "AMD EPYC",
                                                   "loadavg": [4.9, 5.0, 5.1],
                                                   "time_utc": "2026-11-25T16:30:00Z"}}]
        for m, ms in (("inpaintfusion", 100), ("patchmatch_colour_only", 90), ("telea", 40),
                      ("plane_ring", 1), ("inpaintfusion_depth_domain", 95)):
            for k, cls in enumerate(("2-5%", "10-20%", "30-40%")):
                lines.append(summary(m, cls, ms * (k + 1), 70.0 + 60 * k))
        lines.append(summary("inpaintfusion_propagated", "10-20%", 200, 150.0))
        lines.append(summary("telea_new", "10-20%", 20, None))  # null MAE (nlohmann NaN): not drawn
        with tempfile.TemporaryDirectory() as d:
            src = self.write(d, lines)
            png = os.path.join(d, "t.png")
            out = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                                 capture_output=True, text=True, check=True).stdout
            self.assertIn("17 summary lines", out)
            img = mpimg.imread(png)
            self.assertEqual(img.shape[:2], (500, 860))
            self.assertGreater(img.std(), 0.01)  # not a blank canvas

    def test_no_summaries_or_bad_lines_are_errors(self):
        with tempfile.TemporaryDirectory() as d:
            png = os.path.join(d, "t.png")
            src = self.write(d, [{"bench": "inpaint", "method": "telea", "class": "2-5%"}])
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                               capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("no \"inpaint_summary\" lines", r.stderr)
            src = self.write(d, [{"bench": "inpaint_summary", "method": "telea", "class": "2-5%",
                                  "ms_p50": 3.0}])
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", png],
                               capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("depth_mae_mm", r.stderr)
            self.assertFalse(os.path.exists(png))


if __name__ == "__main__":
    unittest.main()
