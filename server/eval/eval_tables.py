#!/usr/bin/env python3
"""Markdown tables for docs/evaluation.md from exoview_eval JSON lines.

  python3 server/eval/eval_tables.py results.jsonl
"""
import json
import sys


def main(path):
    rows = [json.loads(l) for l in open(path) if l.strip().startswith("{")]
    ev = [r for r in rows if r.get("bench") == "eval"]
    # Older lines carry no "test_poses": in the full suite the second vertex_color block of a
    # dataset is the near-trajectory run.
    seen = {}
    for r in ev:
        if "test_poses" in r:
            continue
        if r["config"]["policy"] == "vertex_color":
            seen[r["dataset"]] = seen.get(r["dataset"], 0) + 1
        if r["dataset"].startswith("7scenes"):
            r["test_poses"] = "held_out"
        elif r["proxy"] == "tsdf" and r["tag"] == "main" and seen.get(r["dataset"], 0) == 2 and r["config"]["frames"] == 500:
            r["test_poses"] = "near"
        else:
            r["test_poses"] = "scene"

    def key(r):
        return (r["dataset"], r["proxy"], r["tag"])

    print("| dataset | proxy | test poses | policy | frames | store | views | MSSIM | MSSIM covered | PSNR | coverage | surface | integrate ms med/p95 | plan ms med/p95 | Consider ms med | render ms | store MB | geometry MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ev:
        if r["tag"] not in ("main", "baseline"):
            continue
        c, q, s, m = r["config"], r["quality"], r["speed"], r["memory"]
        print(f"| {r['dataset']} | {r['proxy']} {c['voxel_m'] or ''} | {r['test_poses']} | {c['policy']} | {c['frames']} | {c['store']} | {r['views']} | "
              f"{q['mssim']:.4f} | {q['mssim_covered']:.4f} | {q['psnr']:.2f} | {q['coverage']:.3f} | {q.get('surface', 0):.3f} | "
              f"{s['integrate_ms_median']:.1f} / {s['integrate_ms_p95']:.1f} | {s['plan_ms_median']:.2f} / {s['plan_ms_p95']:.2f} | "
              f"{s['consider_ms_median']:.3f} | {s['render_ms_median']:.0f} | {m['store_bytes']/1e6:.0f} | {m['geometry_bytes']/1e6:.1f} |")
    print()
    print("| dataset | sweep | value | MSSIM | PSNR | coverage | views | accepted | plan ms med | Consider ms med |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    field = {"sweep_store": "store", "sweep_r_max": "r_max", "sweep_lambda": "lambda",
             "sweep_cell": "cell_m", "sweep_dts": "delta_tau_sum"}
    for r in ev:
        if not r["tag"].startswith("sweep"):
            continue
        c, q, s = r["config"], r["quality"], r["speed"]
        print(f"| {r['dataset']} | {r['tag'][6:]} | {c[field[r['tag']]]} | {q['mssim']:.4f} | {q['psnr']:.2f} | {q['coverage']:.3f} | {r['views']} | {r['accepted']} | {s['plan_ms_median']:.2f} | {s['consider_ms_median']:.3f} |")
    for r in rows:
        if r.get("bench") == "eval_split":
            print()
            print(f"7-Scenes split: ingested {r['ingested']}, held out {r['held_out']}, dropped (duplicate colour) {r['dropped_duplicate_colour']}, evaluated {r['test_views']}")


if __name__ == "__main__":
    main(sys.argv[1])
