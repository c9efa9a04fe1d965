#!/usr/bin/python3
"""Session 15 diagnostic: per test view, policy NEW against BASE (default min_distance) on the
near test poses: the summed SSIM difference, the views whose nearest stored camera centre is more
than 0.5 m farther than BASE's and their share of the difference, the correlation of the per-view
SSIM and nearest-centre differences, the mean nearest-centre distance and the mean coverage.

  nearest.py FILE... [--base min_distance] [--new online]   (exoview_eval --per_view 1 output)
"""
import argparse, json, statistics as st

ap = argparse.ArgumentParser()
ap.add_argument("files", nargs="+")
ap.add_argument("--base", default="min_distance")
ap.add_argument("--new", nargs="+", default=["online"])
a = ap.parse_args()
rows = {}
for f in a.files:
    for l in open(f):
        r = json.loads(l)
        if r.get("bench") != "eval" or "per_view" not in r:
            continue
        n = r["config"]["policy"] + ("" if r.get("tag") in (None, "main") else ":" + r["tag"])
        rows[(n, r["test_poses"], r["config"]["store"])] = r
for (n, poses, store) in sorted(rows, key=lambda k: (k[2], k[0])):
    if poses != "near" or n not in a.new or (a.base, poses, store) not in rows:
        continue
    A, B = rows[(n, poses, store)]["per_view"], rows[(a.base, poses, store)]["per_view"]
    ds = [x - y for x, y in zip(A["ssim"], B["ssim"])]
    dn = [x - y for x, y in zip(A["near_m"], B["near_m"])]
    far = [i for i in range(len(ds)) if dn[i] > 0.5]
    print(f"store {store} {n} - {a.base}: sum dSSIM {sum(ds):+.3f} over {len(ds)} views; "
          f"{len(far)} views with the nearest stored centre > 0.5 m farther, their dSSIM "
          f"{sum(ds[i] for i in far):+.3f}; corr(dSSIM, dnearest) {st.correlation(ds, dn):+.2f}; "
          f"mean nearest centre {st.mean(A['near_m']):.2f} vs {st.mean(B['near_m']):.2f} m; "
          f"coverage {st.mean(A['coverage']):.4f} vs {st.mean(B['coverage']):.4f}")
