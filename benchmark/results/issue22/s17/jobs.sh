# jobs.sh (sourced by queue*.sh): job SCENE STREAM SEED POLICIES OUT runs run.sh and appends its
# wall / CPU time and the load to runs.log. Run from this folder.
ALL=online,min_distance,every_n_online,reservoir,keyframe,every_n
job() {
  local t0=$(date +%s)
  ./run.sh "$@"; local rc=$?
  echo "$1 $2 s$3 [$4] rc $rc $(( $(date +%s) - t0 )) s: $(tail -1 $5.log); $(date -u +%H:%M) load $(cut -d' ' -f1-3 /proc/loadavg)" >> runs.log
}
