#!/usr/bin/python3
"""merge.py OUT S14FILE NEWFILE...: the session-14 rows of the product's current default and the
baselines (apartment files: `online:ozc=1` renamed `online`, the `main` online rows = the old
default dropped; every_n / min_distance `main`), then every row of the new files."""
import json, sys
out = open(sys.argv[1], 'w')
apart = 'ozc=1' in open(sys.argv[2]).read()
for l in open(sys.argv[2]):
    r = json.loads(l)
    if r.get('bench') != 'eval': continue
    p, tag = r['config']['policy'], r.get('tag')
    if p == 'online':
        if apart and tag == 'ozc=1': r['tag'] = 'main'
        elif apart or tag != 'main': continue
    elif p in ('every_n', 'min_distance'):
        if tag != 'main': continue
    else: continue
    out.write(json.dumps(r) + '\n')
for f in sys.argv[3:]:
    for l in open(f): out.write(l)
