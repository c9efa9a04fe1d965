#!/usr/bin/python3
"""(usage: mk_table.py [RESULTS_DIR]) Session 18 (lead) table: product path, governor off, per store and policy over the folds."""
import json, sys, statistics, glob, os
R = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__))
def load(files):
    out = {}
    for f in files:
        if not os.path.exists(f): continue
        ing = {}
        for l in open(f):
            j = json.loads(l)
            if j.get("bench") == "product_eval_ingest": ing[j["fold"]] = j
            if j.get("method") == "lumigraph_product":
                q = j["quality"]; i = ing.get(j["fold"], {})
                out[j["fold"]] = dict(ssim=q["ssim"], psnr=q["psnr"], unf=q["ssim_unfilled"], cov=q["coverage"],
                                      ms=q.get("ms_ssim"), gmsd=q.get("gmsd"), acc=i.get("planning_accepted"),
                                      dropped=i.get("dropped"), vkb=i.get("viewer_view_bytes"))
    return out
rows = []
for S in (50, 100, 200):
    pol = {"lumigraph": load([f"{R}/g_s{S}.jsonl", f"{R}/t{S}_lumi.jsonl"]),
           "every_n": load([f"{R}/t{S}_evn.jsonl", os.path.join(R, "..", "s17", f"product_eval_store{S}_every_n.jsonl")]),
           "min_distance": load([f"{R}/t{S}_mind.jsonl", f"{R}/t{S}_mind_b.jsonl"])}
    L = pol["lumigraph"]
    for p, d in pol.items():
        if not d: continue
        folds = sorted(d)
        m = lambda k: statistics.mean(d[f][k] for f in folds)
        sd = lambda k: statistics.pstdev(d[f][k] for f in folds)
        line = f"| {S} | {p} | {len(folds)} ({','.join(map(str,folds))}) | {m('ssim'):.4f} ± {sd('ssim'):.4f} | {m('psnr'):.2f} | {m('unf'):.4f} | {m('cov'):.3f} | {m('ms'):.4f} | {m('gmsd'):.4f} |"
        if p != "lumigraph":
            common = [f for f in folds if f in L]
            if common:
                ds = [L[f]['ssim'] - d[f]['ssim'] for f in common]
                dp = [L[f]['psnr'] - d[f]['psnr'] for f in common]
                wins = sum(1 for x in ds if x > 0)
                line += f" {statistics.mean(ds):+.4f} / {statistics.mean(dp):+.2f} dB ({wins}/{len(common)} folds) |"
            else: line += " |"
        else: line += " |"
        accs = [d[f]['acc'] for f in folds if d[f]['acc'] is not None]
        line += f" {statistics.mean(accs):.0f} |" if accs else " – |"
        drops = [d[f]['dropped'] for f in folds if d[f]['dropped'] is not None]
        line += f" {sum(drops)} |"
        rows.append(line)
print("| store | policy | folds | SSIM mean ± sd | PSNR dB | unfilled SSIM | coverage | MS-SSIM | GMSD | lumigraph − policy, SSIM / PSNR (folds won) | frames accepted (mean) | dropped |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
print("\n".join(rows))
