#!/usr/bin/python3
"""Session 17's tables (issue 22): wins / ties / losses of the online planner against every online
baseline and the length-aware oracle, with two spreads per cell.

Reads exoview_eval JSON lines run with --per_view 1 (files SCENE_STREAM_sSEED.jsonl, any number
of policies per file; rows are named POLICY or POLICY:TAG). For each (stream, test poses, store)
and baseline B the paired difference planner - B is taken per test view (same poses, same store
size), averaged per seed (d_s), then over seeds (D). Two spreads:
  sd_seeds = the sample sd of d_s over seeds (scene + stream + test poses all change with a seed);
  se_views = the standard error of D from the test views alone, sqrt(sum_s var_i(d_si)/n_s) / S.
Verdict: win (loss) when every seed has the planner better (worse) and |D| > 2 se_views; else tie.
--views N uses only the first N test views of every run (the 64-pose sets start with the 16 poses
of sessions 13-16: the sampler draws them in sequence), to show the spread before / after.

  summary.py [--new online] [--views 16] [--metric ssim] FILES
"""
import argparse
import collections
import json
import math
import statistics as st

BASELINES = ["min_distance", "every_n_online", "reservoir", "keyframe"]
ORACLE = "every_n"
LABEL = {"min_distance": "min-distance", "every_n_online": "prog. every-N", "reservoir": "reservoir",
         "keyframe": "keyframes", "every_n": "every-N (oracle)"}


def load(files, views, metric="ssim"):
    data = collections.defaultdict(dict)  # (stream, poses, name, store) -> {seed: [per-view ssim]}
    for path in files:
        for line in open(path):
            line = line.strip()
            if not line:
                continue
            r = json.loads(line)
            if r.get("bench") != "eval" or "config" not in r:
                continue
            if "per_view" not in r:  # older rows (session 14): the mean alone
                if metric != "ssim":
                    continue
                r["per_view"] = {"ssim": [r["quality"]["mssim"]]}
            c = r["config"]
            name = c["policy"] + ("" if r.get("tag") in (None, "main") else ":" + r["tag"])
            ds = r["dataset"].split("/seed")
            stream = ds[0]
            seed = int(ds[1].split("/")[0]) if len(ds) > 1 else 1
            key = "ssim" if metric == "ssim" else metric
            pv = r["per_view"][key] if key in r["per_view"] else [r["quality"][key]]
            data[(stream, r["test_poses"], name, c["store"])][seed] = pv[:views] if views else pv
    return data


def paired(a, b):
    """a, b: {seed: per-view list}. Returns (D, sd_seeds, se_views, wins, n) or None."""
    seeds = sorted(set(a) & set(b))
    if not seeds:
        return None
    ds, var = [], 0.0
    for s in seeds:
        d = [x - y for x, y in zip(a[s], b[s])]
        ds.append(st.mean(d))
        var += (st.variance(d) / len(d)) if len(d) > 1 else 0.0
    D = st.mean(ds)
    sd = st.stdev(ds) if len(ds) > 1 else float("nan")
    se = math.sqrt(var) / len(seeds)
    return D, sd, se, sum(x > 0 for x in ds), len(ds), sum(x < 0 for x in ds)


def verdict(p):
    D, sd, se, wins, n, losses = p
    if wins == n and D > 2 * se:
        return "**win**"
    if losses == n and -D > 2 * se:
        return "**loss**"
    return "tie"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--new", default="online")
    ap.add_argument("--views", type=int, default=0)
    ap.add_argument("--spread", action="store_true", help="only the spread table (planner - each)")
    ap.add_argument("--compact", action="store_true",
                    help="one row per (stream, poses, row): D @ each store with its verdict")
    ap.add_argument("--cause", action="store_true",
                    help="per policy: mean over seeds and test views of the nearest stored camera "
                         "centre (m), its turn (deg) and the blend coverage")
    args = ap.parse_args()
    if args.cause:
        cause(args)
        return
    if args.compact:
        compact(args)
        return
    data = load(args.files, args.views)
    groups = sorted({(k[0], k[1]) for k in data})
    for stream, poses in groups:
        names = sorted({k[2] for k in data if k[:2] == (stream, poses)})
        stores = sorted({k[3] for k in data if k[:2] == (stream, poses)})
        new = {s: data.get((stream, poses, args.new, s)) for s in stores}
        if not any(new.values()):
            continue
        nseeds = max(len(v) for v in new.values() if v)
        nviews = min(len(x) for v in new.values() if v for x in v.values())
        print(f"\n**{stream}, {poses}** ({nseeds} seeds, {nviews} test views each; "
              f"{args.new} − row: mean, seeds better, sd over seeds, se from views, verdict)\n")
        print("| row | " + " | ".join(str(s) for s in stores) + " |")
        print("|---|" + "---|" * len(stores))
        cells = []
        for s in stores:
            v = new[s]
            m = [st.mean(x) for x in v.values()] if v else []
            cells.append("%.4f ± %.4f" % (st.mean(m), st.stdev(m) if len(m) > 1 else 0) if m else "–")
        print(f"| {args.new} (SSIM, mean ± sd over seeds) | " + " | ".join(cells) + " |")
        order = [n for n in BASELINES + [ORACLE] if n in names] + \
                [n for n in names if n not in BASELINES + [ORACLE, args.new]]
        for n in order:
            cells = []
            for s in stores:
                b = data.get((stream, poses, n, s))
                p = paired(new[s], b) if new[s] and b else None
                if not p:
                    cells.append("–")
                    continue
                D, sd, se, wins, k, _ = p
                bm = st.mean(st.mean(x) for x in b.values())
                extra = ""
                if n == ORACLE:
                    extra = " = %+.2f %%" % (100 * D / bm)
                    cells.append("%+.4f%s (%d/%d, sd %.4f, se %.4f)" % (D, extra, wins, k, sd, se))
                else:
                    cells.append("%+.4f (%d/%d, sd %.4f, se %.4f) %s" % (D, wins, k, sd, se, verdict(p)))
            print(f"| − {LABEL.get(n, n)} | " + " | ".join(cells) + " |")


def compact(args):
    data = load(args.files, args.views)
    groups = sorted({(k[0], k[1]) for k in data})
    print("| stream, poses (seeds) | planner − | 50 | 100 | 200 |")
    print("|---|---|---|---|---|")
    for stream, poses in groups:
        names = sorted({k[2] for k in data if k[:2] == (stream, poses)})
        stores = sorted({k[3] for k in data if k[:2] == (stream, poses)})
        order = [n for n in BASELINES + [ORACLE] if n in names] + \
                [n for n in names if n not in BASELINES + [ORACLE, args.new]]
        for n in order:
            cells, nseeds = [], 0
            for s in stores:
                a, b = data.get((stream, poses, args.new, s)), data.get((stream, poses, n, s))
                p = paired(a, b) if a and b else None
                if not p:
                    cells.append("–")
                    continue
                nseeds = max(nseeds, p[4])
                if n == ORACLE:
                    bm = st.mean(st.mean(x) for x in b.values())
                    cells.append("%+.4f (%+.2f %%)" % (p[0], 100 * p[0] / bm))
                else:
                    v = verdict(p).replace("**", "")
                    cells.append("%+.4f %s" % (p[0], v if v != "tie" else "tie"))
            print(f"| {stream}, {poses} ({nseeds}) | {LABEL.get(n, n)} | " + " | ".join(cells) + " |")


def cause(args):
    ds = {m: load(args.files, args.views, m) for m in ("near_m", "near_deg", "coverage", "ssim")}
    keys = sorted(ds["ssim"], key=lambda k: (k[0], k[1], k[3], k[2]))
    print("| stream, poses | store | policy | SSIM | nearest centre m | its turn deg | coverage |")
    print("|---|---|---|---|---|---|---|")
    for k in keys:
        row = []
        for m in ("ssim", "near_m", "near_deg", "coverage"):
            v = ds[m].get(k, {})
            row.append("%.4f" % st.mean(x for l in v.values() for x in l) if v else "–")
        print(f"| {k[0]}, {k[1]} | {k[3]} | {k[2]} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
