#!/bin/bash
# queue.sh: session 17's runs, one exoview_eval at a time (2 shared cores); times -> runs.log.
here=$(cd "$(dirname "$0")" && pwd); cd "$here"
. ./jobs.sh
mkdir -p dev
for job in "$@"; do
  case $job in
    ad1) job apartment drone 1 $ALL,online:drs=0.5 dev/apartment_drone_s1.jsonl ;;
    vd) for s in 1 2 3; do job village drone $s $ALL,online:drs=0.5 dev/village_drone_s$s.jsonl; done ;;
    ad) for s in 2 3; do job apartment drone $s $ALL,online:drs=0.5 dev/apartment_drone_s$s.jsonl; done ;;
    ah) for s in 1 2 3; do job apartment handheld $s $ALL,online:drs=0.5 dev/apartment_handheld_s$s.jsonl; done ;;
    vh) for s in 1 2 3; do job village handheld $s $ALL,online:drs=0.5 dev/village_handheld_s$s.jsonl; done ;;
  esac
done
# (appended) single seeds: ah1 / vh1 / ad2
for job in "$@"; do
  case $job in
    ah1) job apartment handheld 1 $ALL,online:drs=0.5 dev/apartment_handheld_s1.jsonl ;;
    vh1) job village handheld 1 $ALL,online:drs=0.5 dev/village_handheld_s1.jsonl ;;
  esac
done
