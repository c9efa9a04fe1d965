#!/usr/bin/python3
"""Paired comparison of policies over folds or seeds (issues 15 / 22).

Reads exoview_eval JSON lines (one file per 7-Scenes fold or per synthetic seed), names each row
POLICY or POLICY:TAG (the eval's policy options), and prints per (stream, test poses) a markdown
table: SSIM mean ± sample sd over the runs at each store, and for each policy the paired
difference NEW - policy (mean over runs) with the runs where NEW is better (wins / runs).

  tools/paired_table.py --new online:dwe=0.8 DIR/fold_*.jsonl
  tools/paired_table.py --new online:dwe=0.8 --metric psnr DIR/apartment_drone_s*.jsonl
"""
import argparse
import collections
import json
import statistics as st


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--new", required=True, help="the policy the others are paired against")
    ap.add_argument("--metric", default="mssim")
    args = ap.parse_args()
    data = collections.defaultdict(dict)  # (stream, poses, name, store) -> {run: value}
    for path in args.files:
        for line in open(path):
            line = line.strip()
            if not line:
                continue
            r = json.loads(line)
            if r.get("bench") != "eval" or "config" not in r or r["config"]["policy"] == "vertex_color":
                continue
            c = r["config"]
            name = c["policy"] + ("" if r.get("tag") in (None, "main") else ":" + r["tag"])
            stream = r["dataset"].split("/seed")[0]
            data[(stream, r["test_poses"], name, c["store"])][path] = r["quality"][args.metric]
    groups = sorted({(k[0], k[1]) for k in data})
    for stream, poses in groups:
        names = sorted({k[2] for k in data if k[:2] == (stream, poses)})
        stores = sorted({k[3] for k in data if k[:2] == (stream, poses)})
        runs = max(len(v) for k, v in data.items() if k[:2] == (stream, poses))
        print(f"\n| {stream}, {poses} ({runs} runs), {args.metric} | " +
              " | ".join(str(s) for s in stores) + " |")
        print("|---|" + "---|" * len(stores))
        for n in [args.new] + [x for x in names if x != args.new]:
            cells = []
            for s in stores:
                v = data.get((stream, poses, n, s))
                if not v:
                    cells.append("–")
                    continue
                vals = list(v.values())
                cell = "%.4f ± %.4f" % (st.mean(vals), st.stdev(vals) if len(vals) > 1 else 0.0)
                nv = data.get((stream, poses, args.new, s))
                if nv and n != args.new:
                    d = [nv[x] - v[x] for x in nv if x in v]
                    if d:
                        cell += " (%+.4f, %d/%d)" % (st.mean(d), sum(x > 0 for x in d), len(d))
                cells.append(cell)
            print(f"| {n} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
