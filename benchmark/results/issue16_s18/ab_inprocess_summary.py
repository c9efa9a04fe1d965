#!/usr/bin/python3
# Summary of vulkan_loop_ab_probe.py runs (JSONL rows {"rep", "uptime_before", "args", "row"}): paired
# per-frame CPU ratios new/old per configuration, median with an order-statistic 95 % interval.
import json, statistics as st, collections, sys
g = collections.OrderedDict()
for f in sys.argv[1:]:
    for l in open(f):
        d = json.loads(l); r = d['row']
        k = (r['scene'], r['width'], r['refs_per_cell'], r['background_views'], r['fill_holes'])
        e = g.setdefault(k, {'q': [], 'new': [], 'old': [], 'runs': 0, 'load': []})
        e['q'] += [a / b for a, b in zip(r['ab_cpu_new'], r['ab_cpu_old'])]
        e['new'] += r['ab_cpu_new']; e['old'] += r['ab_cpu_old']; e['runs'] += 1; e['load'].append(d['uptime_before'])
for k, e in g.items():
    q = sorted(e['q']); n = len(q)
    # sign test-ish and a bootstrap-free CI: the order statistics around the median
    lo, hi = q[max(0, int(n / 2 - 1.96 * n ** 0.5 / 2))], q[min(n - 1, int(n / 2 + 1.96 * n ** 0.5 / 2))]
    print(k, f"runs {e['runs']} pairs {n}: paired ratio new/old median {st.median(q):.3f} (95% CI {lo:.3f}-{hi:.3f}), lower in {sum(x < 1 for x in q)}/{n}; CPU ms median new {st.median(e['new']):.1f} old {st.median(e['old']):.1f}; load {min(e['load'])}-{max(e['load'])}")
