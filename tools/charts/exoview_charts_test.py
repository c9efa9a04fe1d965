#!/usr/bin/python3
"""Tests of exoview_charts.py: flattening of nested eval lines, which charts get data, and that
the PNGs written are images of the expected size."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import matplotlib.image as mpimg

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import exoview_charts as ec  # noqa: E402


def line(dataset, tag, **kw):
    cfg = {"policy": kw.pop("policy", "online"), "store": kw.pop("store", 100),
           "r_max": kw.pop("r_max", 16), "lambda": kw.pop("lam", 0.5),
           "cell_m": kw.pop("cell_m", 1.0), "voxel_m": kw.pop("voxel_m", 0.15),
           "delta_tau_sum": kw.pop("dts", 0.05)}
    return {"bench": "eval", "dataset": dataset, "tag": tag, "proxy": kw.pop("proxy", "tsdf"),
            "test_poses": kw.pop("test_poses", "scene"), "config": cfg,
            "quality": {"mssim": kw.pop("mssim", 0.8)},
            "speed": {"integrate_ms_median": 10.0, "plan_ms_median": 2.0},
            "integrate_cpu": {"integrate_cpu_ms_median": kw.pop("cpu_ms", 30.0)}}


class ChartsTest(unittest.TestCase):
    def test_flatten_finds_nested_keys_and_top_level_wins(self):
        f = ec.flatten({"mssim": 1, "quality": {"mssim": 2, "psnr": 3}, "a": {"b": {"c": 4}}})
        self.assertEqual(f["mssim"], 1)
        self.assertEqual(f["psnr"], 3)
        self.assertEqual(f["c"], 4)

    def test_writes_the_charts_that_have_data(self):
        rows = [line("village/flyover", "sweep_store", store=s, mssim=0.7 + s / 1e4)
                for s in (25, 50, 100)]
        rows += [line("apartment/walk", "sweep_lambda", lam=l, mssim=0.5 + l / 10)
                 for l in (0.0, 0.5, 1.0)]
        rows += [line("village/flyover", "voxel_fixedlod", voxel_m=v, cpu_ms=3 / v,
                      test_poses=t, mssim=0.9 - v) for v in (0.1, 0.2) for t in ("near", "scene")]
        rows.append({"bench": "other", "dataset": "village/flyover"})
        with tempfile.TemporaryDirectory() as d:
            src = os.path.join(d, "r.jsonl")
            with open(src, "w") as f:
                f.write("\n".join(json.dumps(r) for r in rows) + "\n\n")
            out = subprocess.run([sys.executable, os.path.join(HERE, "exoview_charts.py"), src,
                                  "--out", os.path.join(d, "png")],
                                 capture_output=True, text=True, check=True).stdout
            for name, size in (("eval_store", (400, 640)), ("eval_sweeps", (720, 1120)),
                               ("eval_voxel", (440, 1120)), ("eval_speed_error", (420, 1120))):
                img = mpimg.imread(os.path.join(d, "png", name + ".png"))
                self.assertEqual(img.shape[:2], size, name)
                self.assertGreater(img.std(), 0.01, name)  # not a blank canvas
            self.assertIn("wrote", out)

    def test_no_data_writes_nothing_and_bad_json_is_an_error(self):
        with tempfile.TemporaryDirectory() as d:
            src = os.path.join(d, "r.jsonl")
            with open(src, "w") as f:
                f.write(json.dumps({"bench": "planning"}) + "\n")
            out = subprocess.run([sys.executable, os.path.join(HERE, "exoview_charts.py"), src,
                                  "--out", d], capture_output=True, text=True, check=True).stdout
            self.assertEqual(out.count("no data"), 4)
            self.assertFalse([p for p in os.listdir(d) if p.endswith(".png")])
            with open(src, "a") as f:
                f.write("{not json\n")
            r = subprocess.run([sys.executable, os.path.join(HERE, "exoview_charts.py"), src,
                                "--out", d], capture_output=True, text=True)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("r.jsonl:2", r.stderr)


if __name__ == "__main__":
    unittest.main()
