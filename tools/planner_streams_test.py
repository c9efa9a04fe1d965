#!/usr/bin/python3
"""Test of tools/planner_streams.py --summarize: mean / sd over seeds, paired verdicts (win / loss
only when every seed agrees, else tie), the novelty planner kept apart from the thesis planner,
summary.json and the chart written; an empty directory is an error."""
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "planner_streams.py")


def line(policy, store, poses, mssim, novelty=0, views=None):
    return json.dumps({
        "bench": "eval", "dataset": "apartment/drone", "test_poses": poses,
        "config": {"policy": policy, "store": store, "frames": 5000, "online": 1,
                   "novelty_positional": novelty},
        "quality": {"mssim": mssim, "psnr": 20.0, "coverage": 0.9, "mssim_unfilled": mssim - 0.05},
        "views": views or store, "memory": {"store_bytes": (views or store) * 1000},
        "speed": {"plan_ms_median": 0.5, "plan_ms_p95": 1.0},
        "plan_cpu_ms": {"median": 0.4, "p95": 0.9}})


def main():
    with tempfile.TemporaryDirectory() as d:
        r = subprocess.run([sys.executable, SCRIPT, "--out", d, "--summarize"],
                           capture_output=True, text=True)
        assert r.returncode != 0 and "no eval lines" in r.stderr, r.stderr
        # Seed 1 / 2: online 0.80 / 0.82, min-distance 0.85 / 0.86 (loss on both), reservoir
        # 0.79 / 0.83 (mixed: tie), novelty planner 0.84 / 0.84.
        vals = {1: {"online": 0.80, "min_distance": 0.85, "reservoir": 0.79, "nov": 0.84},
                2: {"online": 0.82, "min_distance": 0.86, "reservoir": 0.83, "nov": 0.84}}
        for seed, v in vals.items():
            with open(os.path.join(d, f"apartment_drone_s{seed}.jsonl"), "w") as f:
                for store in (50, 100):
                    f.write(line("online", store, "near", v["online"]) + "\n")
                    f.write(line("online", store, "near", v["nov"], novelty=1) + "\n")
                    f.write(line("min_distance", store, "near", v["min_distance"]) + "\n")
                    f.write(line("reservoir", store, "near", v["reservoir"]) + "\n")
                    f.write(line("every_n", store, "near", 0.81) + "\n")
        png = os.path.join(d, "chart.png")
        r = subprocess.run([sys.executable, SCRIPT, "--out", d, "--summarize", "--chart", png],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert os.path.getsize(png) > 10000
        s = json.load(open(os.path.join(d, "summary.json")))
        cell = [c for c in s["cells"] if c["policy"] == "online" and c["store"] == 50][0]
        assert abs(cell["mssim"] - 0.81) < 1e-9 and abs(cell["mssim_sd"] - 0.0141421356) < 1e-6
        assert cell["n_seeds"] == 2
        nov = [c for c in s["cells"] if c["policy"] == "online_novelty" and c["store"] == 50][0]
        assert abs(nov["mssim"] - 0.84) < 1e-9
        paired = {(p["planner"], p["vs"], p["store"]): p for p in s["paired"]}
        md = paired[("online", "min_distance", 50)]
        assert md["verdict"] == "loss" and abs(md["delta"] + 0.045) < 1e-9, md
        assert paired[("online", "reservoir", 50)]["verdict"] == "tie"
        assert paired[("online_novelty", "every_n", 100)]["verdict"] == "win"
        assert "| apartment / drone / near | 50 | min-distance |" in r.stdout, r.stdout
    print("planner_streams_test: ok")


if __name__ == "__main__":
    main()
