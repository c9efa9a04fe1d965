#!/usr/bin/python3
"""The protocol gap (issue 22, session 17): the same seed and test poses under sessions 13-16's
--scale bounds (16 test views) and this session's --scale server (the first 16 of its 64 views,
then all 64). Prints planner - baseline per store for each rule.

  gap.py OLD.jsonl NEW.jsonl    (one seed of one stream each)
"""
import sys
sys.path.insert(0, __import__("os").path.dirname(__file__))
import statistics as st
from summary import load

old, new = sys.argv[1], sys.argv[2]
runs = [("bounds, 16 views", load([old], 16)), ("server, 16 views", load([new], 16)),
        ("server, 64 views", load([new], 64))]
keys = sorted({(k[0], k[1], k[3]) for _, d in runs for k in d})
print("| stream, poses | store | rule | d_max | planner SSIM | − min-distance | − every-N (oracle) | − s = 0.5 |")
print("|---|---|---|---|---|---|---|---|")
import json
dm = {}
for path, label in ((old, "bounds"), (new, "server")):
    for line in open(path):
        r = json.loads(line)
        if r.get("config", {}).get("policy") == "online":
            dm[label] = r["config"]["d_max_m"]
for stream, poses, store in keys:
    for label, d in runs:
        def m(name):
            v = d.get((stream, poses, name, store))
            return st.mean(x for l in v.values() for x in l) if v else None
        p = m("online")
        if p is None:
            continue
        cells = ["%+.4f" % (p - m(n)) if m(n) is not None else "–"
                 for n in ("min_distance", "every_n", "online:drs=0.5")]
        print(f"| {stream}, {poses} | {store} | {label} | {dm.get(label.split(',')[0], '?')} | %.4f | " % p
              + " | ".join(cells) + " |")
