#!/usr/bin/env bash
# Reproduces everything in weights/ from scratch, or resumes an interrupted run.
#
#   scripts/train_weights.sh            # from scratch (about 6 h of CPU on this project's 2 cores)
#   scripts/train_weights.sh --resume   # continue the runs in train/runs/ where they stopped
#
# Each stage checkpoints (pretraining every few minutes, the head every 5 minutes) and `--resume`
# continues exactly, so the script can be stopped and restarted at will: a stage whose target is
# already reached returns at once. Stages: pretraining (p7_short_blur's recipe, every schedule
# over 30,000 pairs; the shipped encoder is its student at the end) -> shared head and native
# pathway head (HEAD_STEPS steps each) -> both heads trained on ground truth (GT_HEAD_STEPS,
# each from a cache of 8,000 encoded crops; the native one shipped as its midpoint with its
# start) -> ONNX exports and state dicts -> measurements (controlled benchmark and no-linkage probe for
# the trained encoder and the random init, head vs StereoSGBM on the eval split) -> int8 blob ->
# MANIFEST.json. Set BINO_THREADS to change the torch thread count (default 2).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

resume=()
if [[ "${1:-}" == "--resume" ]]; then
  resume=(--resume)
elif [[ -n "${1:-}" ]]; then
  echo "usage: $0 [--resume]" >&2
  exit 2
fi

threads="${BINO_THREADS:-2}"
pretrain_pairs=30000
head_steps="${HEAD_STEPS:-1000}"
pre=runs/p7_short_blur
head=runs/head_p7
gt_head=runs/hgt40_p7
gt_cache=runs/headcache/gt40_p7_8000_d16.pt
gt_steps="${GT_HEAD_STEPS:-20000}"
native_head=runs/hnat_p7
gt_native_head=runs/hgt40nat_p7
gt_native_cache=runs/headcache/gt40nat_p7_8000_d16.pt
shipped_native_head=runs/hgt40nat_p7_mid
# The student snapshot the run writes at its final evaluation (--eval-student).
encoder="$pre/student_$(printf %07d "$pretrain_pairs").pt"
weights="$BINO_ROOT/weights"
data="${BINO_DATA:-$BINO_ROOT/../shared/data}"
py() { (cd train && "$BINO_VENV/bin/python" -W ignore "$@"); }
step() { printf '\n== %s\n' "$*"; }

scripts/setup.sh

step "pretraining to $pretrain_pairs pairs ($pre)"
if [[ ${#resume[@]} -eq 1 && -f "train/$encoder" && ! -f "train/$pre/last.pt" ]]; then
  # A resume point without the pretraining's optimiser state (train/checkpoints/README.md keeps
  # only the final student): the stage is done.
  echo "pretraining done: train/$encoder"
elif [[ ${#resume[@]} -eq 0 ]]; then
  py -m bino_train.pretrain --out "$pre" --pairs "$pretrain_pairs" --schedule-pairs 30000 \
    --lr 5e-4 --threads "$threads" --teacher-clean --head-bn --momentum 0.99 --blur-prob 0.25 \
    --eval-minutes 10 --eval-student
else
  py -m bino_train.pretrain --out "$pre" --resume --pairs "$pretrain_pairs" --threads "$threads" \
    --eval-minutes 10 --eval-student
fi

step "shared head to $head_steps steps ($head): synthetic pairs and StereoSGBM pseudo-labels"
if [[ ${#resume[@]} -eq 0 || ! -f "train/$head/last.pt" ]]; then
  py -m bino_train.head_train --encoder "$encoder" --out "$head" --steps "$head_steps" \
    --threads "$threads" --no-eval --val-every 0
else
  py -m bino_train.head_train --out "$head" --resume --steps "$head_steps" --threads "$threads" \
    --no-eval --val-every 0
fi

# The shipped shared head: the head above trained on for $gt_steps steps with 16 candidates on
# 8,000 cached crops (layered synthetic scenes, the labeled train pairs' ground truth less the
# held-out four, confident StereoSGBM labels); validated on the held-out labeled pairs.
step "shared head on ground truth to $gt_steps steps ($gt_head; cache $gt_cache)"
if [[ ! -f "train/$gt_cache" ]]; then
  py -m bino_train.head_cache --encoder "$encoder" --out "$gt_cache" --count 8000 --threads "$threads" \
    --max-disp 16 --synthetic-fraction 0.4 --labeled-fraction 0.4 --synthetic-kind layered \
    --blur-prob 0.2 --label-weighting lr
fi
if [[ ${#resume[@]} -eq 0 || ! -f "train/$gt_head/last.pt" ]]; then
  py -m bino_train.head_train --encoder "$encoder" --cache "$gt_cache" --out "$gt_head" \
    --steps "$gt_steps" --batch 8 --lr 1e-3 --max-disp 16 --init-head "$head/last.pt" \
    --val-every 500 --checkpoint-minutes 10 --threads "$threads" --no-eval
else
  py -m bino_train.head_train --out "$gt_head" --resume --steps "$gt_steps" --threads "$threads" \
    --checkpoint-minutes 10 --no-eval
fi

step "native pathway head to $head_steps steps ($native_head): the shared head's recipe on the fused grid"
if [[ ${#resume[@]} -eq 0 || ! -f "train/$native_head/last.pt" ]]; then
  py -m bino_train.head_train --encoder "$encoder" --pathway native --out "$native_head" \
    --steps "$head_steps" --threads "$threads" --no-eval --val-every 0
else
  py -m bino_train.head_train --out "$native_head" --resume --steps "$head_steps" --threads "$threads" \
    --no-eval --val-every 0
fi

# The native head above trained on ground truth with the shared head's
# recipe (its own cache of 8,000 one-pass crops), validated with the one-pass check.
step "native head on ground truth to $gt_steps steps ($gt_native_head; cache $gt_native_cache)"
if [[ ! -f "train/$gt_native_cache" ]]; then
  py -m bino_train.head_cache --encoder "$encoder" --out "$gt_native_cache" --count 8000 --threads "$threads" \
    --max-disp 16 --synthetic-fraction 0.4 --labeled-fraction 0.4 --synthetic-kind layered \
    --blur-prob 0.2 --label-weighting lr --pathway native
fi
if [[ ${#resume[@]} -eq 0 || ! -f "train/$gt_native_head/last.pt" ]]; then
  py -m bino_train.head_train --encoder "$encoder" --cache "$gt_native_cache" --pathway native \
    --out "$gt_native_head" --steps "$gt_steps" --batch 8 --lr 1e-3 --max-disp 16 \
    --init-head "$native_head/last.pt" --val-every 500 --checkpoint-minutes 10 --threads "$threads" --no-eval
else
  py -m bino_train.head_train --out "$gt_native_head" --resume --steps "$gt_steps" --threads "$threads" \
    --checkpoint-minutes 10 --no-eval
fi

# The shipped native head is the midpoint of the two native heads in weight space: the head
# trained on ground truth lost on the held-out labeled pairs at w320, the midpoint beats its
# start on every validation set (experiments.json, hgt40nat_p7_mid).
step "native head: the midpoint of $native_head and $gt_native_head ($shipped_native_head)"
py -m bino_train.head_interpolate --start "$native_head/last.pt" --end "$gt_native_head/last.pt" \
  --alpha 0.5 --out "$shipped_native_head/last.pt"

step "exports and state dicts"
py -m bino_train.head --checkpoint "$gt_head/last.pt" --out "$weights/bino_head.onnx" --logits \
  --state-dict "$weights/bino_head.pt"
py -m bino_train.head --checkpoint "$shipped_native_head/last.pt" --out "$weights/bino_native_head.onnx" --logits \
  --state-dict "$weights/bino_native_head.pt"
py -m bino_train.export --checkpoint "$encoder" --attention-rows 0 --row-embedding 6 --out "$weights/bino_encoder.onnx" \
  --state-dict "$weights/bino_encoder.pt"

step "measurements (train/runs/metrics.json)"
metrics=train/runs/metrics
mkdir -p "$metrics"
py -m bino_train.benchmark --checkpoint "$encoder" --threads "$threads" >"$metrics/benchmark_trained.json"
py -m bino_train.benchmark --random-init-seed 0 --threads "$threads" >"$metrics/benchmark_random.json"
py -m bino_train.probe --checkpoint "$encoder" --threads "$threads" >"$metrics/probe_trained.json"
py -m bino_train.probe --random-init-seed 0 --threads "$threads" >"$metrics/probe_random.json"
py -m bino_train.head_eval --encoder "$encoder" --head "$gt_head/last.pt" --threads "$threads" \
  >"$metrics/head_eval_w160.json"

step "int8 blob"
cargo run -q --release --locked -p bino-host --bin bino -- quantize \
  --onnx "$weights/bino_encoder.onnx" --head "$weights/bino_head.onnx" \
  --native-head "$weights/bino_native_head.onnx" --calib "$data" --out "$weights/bino_int8.bin" --force
# The board's learned preset: the same blob without the shared head.
cargo run -q --release --locked -p bino-host --bin bino -- quantize --only native \
  --from "$weights/bino_int8.bin" --out "$weights/bino_int8_native.bin" --force
cargo run -q --release --locked -p bino-host --bin bino -- compare --data "$data" --split eval \
  --profile w160 --onnx "$weights/bino_encoder.onnx" --blob "$weights/bino_int8.bin" \
  --head "$weights/bino_head.onnx" --json "$metrics/int8_compare_w160.json"

step "manifest"
py -m bino_train.manifest --pretrain-run "$pre" --pretrain-pairs "$pretrain_pairs" \
  --pretrain-role student --head-run "$gt_head" --native-head-run "$shipped_native_head" --metrics-dir runs/metrics \
  --experiments experiments.json --out "$weights/MANIFEST.json"
