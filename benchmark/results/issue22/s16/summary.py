#!/usr/bin/python3
"""summary.py FILE...: session 16's candidates against the default planner and the online
baselines, per stream, test-pose set and store: the paired difference candidate - row (mean over
seeds), the seeds where the candidate is better and the spread (min..max of the per-seed
differences). Rows named POLICY or POLICY:TAG as tools/paired_table.py does; the default planner
is `online`. Files: one per (scene, stream, seed), e.g. the session-15 merged rows concatenated
with the new rows (runs are deterministic, so rows of the same seed pair up)."""
import collections, json, statistics as st, sys

short = '--short' in sys.argv  # no min..max (docs tables)
sys.argv = [a for a in sys.argv if a != '--short']
data = collections.defaultdict(dict)  # (stream, poses, name, store) -> {seed: mssim}
for path in sys.argv[1:]:
    for line in open(path):
        r = json.loads(line)
        if r.get('bench') != 'eval' or r['config']['policy'] == 'vertex_color':
            continue
        name = r['config']['policy'] + ('' if r.get('tag') in (None, 'main') else ':' + r['tag'])
        parts = r['dataset'].split('/seed')
        stream, seed = parts[0], (parts[1] if len(parts) > 1 else '1')
        data[(stream, r['test_poses'], name, r['config']['store'])][seed] = r['quality']['mssim']
base = ['online', 'min_distance', 'every_n_online', 'reservoir', 'keyframe', 'every_n']
streams = sorted({(k[0], k[1]) for k in data})
names = sorted({k[2] for k in data})
cands = [n for n in names if n not in base]
for cand in cands:
    print(f'\n### {cand}: candidate − row, mean of paired per-seed differences (seeds better / seeds; min..max)\n')
    stores = sorted({k[3] for k in data})
    print('| stream, poses | row | ' + ' | '.join(str(s) for s in stores) + ' |')
    print('|---|---|' + '---|' * len(stores))
    for stream, poses in streams:
        for b in base:
            cells, any_ = [], False
            for s in stores:
                c = data.get((stream, poses, cand, s), {})
                v = data.get((stream, poses, b, s), {})
                d = [c[x] - v[x] for x in c if x in v]
                if not d:
                    cells.append('–'); continue
                any_ = True
                cells.append('%+.4f (%d/%d)' % (st.mean(d), sum(x > 0 for x in d), len(d)) if short else
                             '%+.4f (%d/%d; %+.3f..%+.3f)' % (st.mean(d), sum(x > 0 for x in d), len(d), min(d), max(d)))
            if any_:
                print(f'| {stream}, {poses} | {b} | ' + ' | '.join(cells) + ' |')
