#!/bin/bash
# tables.sh: session 16's tables. Each (scene, stream, seed)'s session-15 merged rows (default,
# min-distance, every-N, s = 0.5; runs are deterministic, so the rows of one seed pair up) are
# concatenated with this session's rows of the same seed, then summary.py pairs every candidate
# with the default and the baselines. The fresh seeds 4-6 carry their own default and baseline rows.
here=$(cd "$(dirname "$0")" && pwd); s15=$here/../s15; tmp=$(mktemp -d)
for sc in apartment village; do for st in drone handheld; do for s in 1 2 3; do
  cat $s15/$sc/${st}_merged_s$s.jsonl $(ls $here/overlap/${sc}_${st}_s$s.jsonl $here/axis/${sc}_${st}_s$s.jsonl 2>/dev/null) > $tmp/${sc}_${st}_s$s.jsonl
done; done; done
echo "## seeds 1-3 (session 15's default and baselines + overlap and axis rows)"
"$here/summary.py" "$@" $tmp/*.jsonl
echo; echo "## apartment handheld, fresh seeds 4-6"
"$here/summary.py" "$@" $here/fresh/*.jsonl
echo; echo "## store 50, guards (seeds 1-3; apartment drone seed 1)"
for f in $here/guard50/*.jsonl; do b=$(basename $f .jsonl); sc=${b%%_*}; r=${b#*_}; st=${r%_s*}; s=${r##*_s}
  grep '"store": 50,' $s15/$sc/${st}_merged_s$s.jsonl > $tmp/g_$b.jsonl; cat $f >> $tmp/g_$b.jsonl; done
"$here/summary.py" "$@" $tmp/g_*.jsonl
rm -r $tmp
