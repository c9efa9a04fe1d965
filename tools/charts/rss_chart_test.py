#!/usr/bin/python3
"""Tests of rss_chart.py: the flatness figure (deviation from the RSS at --flat_from), the PNG is
an image of the expected size, and input without rss_sample lines is an error."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import matplotlib.image as mpimg

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import rss_chart as rc  # noqa: E402

SCRIPT = os.path.join(HERE, "rss_chart.py")


def sample(frames, rss):
    return {"phase": "rss_sample", "frames": frames, "rss_mb": rss, "heap_in_use_mb": rss * 0.7,
            "heap_free_mb": rss * 0.1, "log_deltas": 4096}


class RssChartTest(unittest.TestCase):
    def test_flatness_is_measured_from_the_first_sample_at_flat_from(self):
        rows = [sample(1000, 100), sample(5000, 200), sample(6000, 204), sample(7000, 190)]
        ref, last, dev = rc.flatness(rows, 5000)
        self.assertEqual((ref, last), (200, 190))
        self.assertAlmostEqual(dev, 0.05)
        self.assertIsNone(rc.flatness(rows, 8000))

    def test_writes_a_png_and_prints_the_deviation(self):
        with tempfile.TemporaryDirectory() as d:
            a, b, png = os.path.join(d, "a.jsonl"), os.path.join(d, "b.jsonl"), os.path.join(d, "r.png")
            with open(a, "w") as f:
                f.write(json.dumps({"phase": "rss_long", "frames": 3000}) + "\n")
                f.write("\n".join(json.dumps(sample(n, 100 + n // 1000)) for n in (1000, 2000, 3000)))
            with open(b, "w") as f:
                f.write("\n".join(json.dumps(sample(n, 90)) for n in (1000, 2000, 3000)))
            out = subprocess.run([sys.executable, SCRIPT, f"x=1={a}", b, "--out", png, "--flat_from",
                                  "2000"], capture_output=True, text=True, check=True).stdout
            self.assertIn("x=1: RSS 102 MB", out)
            self.assertIn("max deviation 1.0 %", out)
            self.assertIn("6 samples", out)
            img = mpimg.imread(png)
            self.assertEqual(img.shape[:2], (440, 1300))
            self.assertGreater(img.std(), 0.01)

    def test_no_samples_is_an_error(self):
        with tempfile.TemporaryDirectory() as d:
            src = os.path.join(d, "e.jsonl")
            with open(src, "w") as f:
                f.write(json.dumps({"phase": "rss_long"}) + "\n")
            r = subprocess.run([sys.executable, SCRIPT, src, "--out", os.path.join(d, "e.png")],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 1)
            self.assertIn("no rss_sample lines", r.stderr)


if __name__ == "__main__":
    unittest.main()
