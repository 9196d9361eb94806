#!/usr/bin/env bash
# Every run in models/eval.json that was trained on a GPU, as it was run: the sets made by the
# release binary, then the runs in parallel on one GPU (nine at a time shared an H100 in about
# 200 s), then the held-out scores. CPU-only machines can run the same lines one at a time
# (training/README.md gives the CPU times).
#
#   NEUSPIKE=./target/release/neuspike TEXTURES=data/textures OUT=runs training/train_all.sh
set -euo pipefail
NEUSPIKE=${NEUSPIKE:-./target/release/neuspike}
TEXTURES=${TEXTURES:-data/textures}
OUT=${OUT:-runs}
P=${PYTHON:-python3}
mkdir -p "$OUT/logs"
[ -d "$OUT/train" ] || "$NEUSPIKE" dataset --split train --per-cell 120 --size 64 --textures "$TEXTURES/train" --out "$OUT/train"
[ -d "$OUT/test" ] || "$NEUSPIKE" dataset --split test --per-cell 16 --size 96 --textures "$TEXTURES/test" --out "$OUT/test"
# Validation: made like the training set, another seed; the held-out set is never used to choose.
[ -d "$OUT/val" ] || "$NEUSPIKE" dataset --split train --seed 1 --per-cell 8 --size 96 --textures "$TEXTURES/train" --out "$OUT/val"

run() {
  local name=$1
  shift
  PYTHONUNBUFFERED=1 $P training/train.py --train "$OUT/train" --steps 5000 --out "$OUT/$name.pt" "$@" \
    > "$OUT/logs/$name.log" 2>&1 &
}
for seed in 0 1; do
  s=$([ "$seed" = 0 ] && echo "" || echo "-seed1")
  for cfg in "fused 16" "fused 24" "spike 16" "event 8" "event 16"; do
    set -- $cfg
    run "$1-$2$s" --base "$2" --mode "$1" --seed "$seed"
  done
  run "fused-8-noaux$s" --base 8 --mode fused --aux none --seed "$seed"
  run "fused-8-grad$s" --base 8 --mode fused --aux grad --seed "$seed"
  wait
done
run fused-8-gpu --base 8 --mode fused
run fused-8-seed1 --base 8 --mode fused --seed 1
run spike-8-seed1 --base 8 --mode spike --seed 1
run spike-24 --base 24 --mode spike
run event-24 --base 24 --mode event
wait
# The second recipe (the shipped small and medium models): 10,000 steps, best on validation.
for cfg in "fused 16 0" "fused 16 1" "fused 8 0" "fused 8 1" "spike 16 0" "spike 8 0"; do
  set -- $cfg
  s=$([ "$3" = 0 ] && echo "" || echo "-seed1")
  run "$1-$2-val$s" --base "$2" --mode "$1" --seed "$3" --steps 10000 --val "$OUT/val"
done
wait
$P training/evaluate.py --test "$OUT/test" "$OUT"/*.pt --json "$OUT/eval.json"
