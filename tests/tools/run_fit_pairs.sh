#!/bin/bash
# Alternating pairs of `scenesim run` + `scenesim fit` (one thread) of a scene from
# two source trees (BENCHMARKS.md, "What the physics fixes of 2026-11-27 (evening)
# cost").  Usage: tests/tools/run_fit_pairs.sh OLD_TREE NEW_TREE [SCENE] [PAIRS]
old=$1; new=$2; scene=${3:-$(dirname "$0")/ipc_stripe_scene.toml}; pairs=${4:-3}
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
for i in $(seq "$pairs"); do
  for v in old new; do
    src=$old; [ $v = new ] && src=$new
    s=$(date +%s.%N)
    PYTHONPATH=$src python -m scenesim.cli run "$scene" -o "$work/$v.fits" --overwrite -q --threads 1
    m=$(date +%s.%N)
    PYTHONPATH=$src python -m scenesim.cli fit "$work/$v.fits" --fitter gls --refpix jwst -o "$work/${v}_g.fits" --overwrite > /dev/null
    e=$(date +%s.%N)
    echo "$v run $(echo "$m - $s" | bc) s fit $(echo "$e - $m" | bc) s load $(cut -d' ' -f1 /proc/loadavg)"
  done
done
