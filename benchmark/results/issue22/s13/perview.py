#!/usr/bin/python3
"""Session 13 drone diagnostic: per test view, the planner's store against min-distance's.

  perview.py drone_store50_perview_s{1,2,3}.jsonl
Each file: one exoview_eval run with --per_view 1 and policies including online and min_distance.
Prints, per file and test-pose set, the SSIM difference (each policy - min_distance) summed over
the test views, how much of it is in views whose blend coverage fell by > 2 points, the worst
view, and the stored views per 1000-frame bin of the 5 000-frame stream.
"""
import json
import sys

BINS = [0, 1000, 2000, 3000, 4000, 5000]
for path in sys.argv[1:]:
    rows = {}
    for line in open(path):
        r = json.loads(line)
        if r.get("bench") != "eval" or r["config"]["policy"] == "vertex_color":
            continue
        name = r["config"]["policy"] + ("" if r.get("tag") in (None, "main") else ":" + r["tag"])
        rows[(name, r["test_poses"])] = r
    for (name, poses), r in sorted(rows.items()):
        if name == "min_distance":
            continue
        b = rows[("min_distance", poses)]["per_view"]
        a = r["per_view"]
        d = [x - y for x, y in zip(a["ssim"], b["ssim"])]
        dc = [x - y for x, y in zip(a["coverage"], b["coverage"])] if "coverage" in a else [0] * len(d)
        lost = [i for i in range(len(d)) if dc[i] < -0.02]
        w = min(range(len(d)), key=lambda i: d[i])
        sel = a["selected"]
        hist = [sum(BINS[k] <= x < BINS[k + 1] for x in sel) for k in range(len(BINS) - 1)]
        hb = [sum(BINS[k] <= x < BINS[k + 1] for x in rows[("min_distance", poses)]["per_view"]["selected"])
              for k in range(len(BINS) - 1)]
        print(f"{path} {poses} {name}: SSIM {r['quality']['mssim']:.4f} vs min-distance "
              f"{rows[('min_distance', poses)]['quality']['mssim']:.4f}; sum of per-view diffs {sum(d):+.3f} "
              f"over {len(d)} views, of it {sum(d[i] for i in lost):+.3f} in the {len(lost)} views with "
              f"coverage -2 points or worse; worst view {w}: {d[w]:+.3f} (coverage "
              f"{a.get('coverage', [0]*len(d))[w]:.3f} vs {b.get('coverage', [0]*len(d))[w]:.3f}); "
              f"views per 1000 frames {hist} vs {hb}")
