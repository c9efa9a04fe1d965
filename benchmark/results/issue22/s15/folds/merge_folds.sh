#!/bin/bash
# Session 15: per fold, the session-14 default rows, the session-12 baselines and the new rows
# (run from the worktree root).
for f in benchmark/results/issue22/s15/folds/fold_?.jsonl; do j=$(basename $f .jsonl); n=${j#fold_}
  /usr/bin/python3 - $n $f > benchmark/results/issue22/s15/folds/merged_$j.jsonl <<'PY'
import json,sys
n=sys.argv[1]
for l in open(f'benchmark/results/issue22/s14/folds/fold_{n}.jsonl'):
  r=json.loads(l)
  if r.get('bench')=='eval' and r['config']['policy']=='online' and r.get('tag')=='main': print(json.dumps(r))
for fn in (f'benchmark/results/issue15/folds_s12_density/store25_fold_{n}.jsonl', f'benchmark/results/issue15/folds_s12_density/store48_95_fold_{n}.jsonl'):
  for l in open(fn):
    r=json.loads(l)
    if r.get('bench')=='eval' and r['config']['policy'] in ('every_n','min_distance') and r.get('tag')=='main': print(json.dumps(r))
for l in open(sys.argv[2]): print(l.strip())
PY
done
