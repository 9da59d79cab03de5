#!/usr/bin/env bash
# Re-measures the docs' accuracy tables (docs/results.md, docs/robustness.md) with the weights
# in weights/: every `bino eval` and `bino compare` run behind them (eval split, StereoSGBM in
# the same run), the JSON into train/checkpoints/metrics/. Run it whenever the blob changes;
# about 25 minutes on 2 cores; then `python3 scripts/render_docs.py` re-renders the tables.
#
#   scripts/measure_tables.sh [NAME...]   # all runs, or only the named ones (eval_w160, ...)
#
# Each run prints its wall time; a failed run stops the script (set -e) and leaves the earlier
# JSON in place.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

data="${BINO_DATA:-$BINO_ROOT/../shared/data}"
metrics=train/checkpoints/metrics
nuisances=gain,gamma,noise,blur,occlude

# name, then the arguments after `bino eval --data DATA --split eval`
runs=(
  "eval_w160|--profile w160"
  "eval_w320|--profile w320 --max-cols 16"
  "eval_nuisance_w160|--profile w160 --readout census+lr+ref,sgm+lr+ref,head+lr+ref,fuse+lr+ref,fuse-all+lr+ref --nuisance $nuisances"
  "eval_nuisance_w320|--profile w320 --max-cols 16 --precision int8 --readout census+lr+ref,sgm+lr+ref,head+lr+ref,fuse+lr+ref,fuse-all+lr+ref --nuisance $nuisances"
  "occlusion_w160|--profile w160 --precision int8 --readout census+lr+ref,sgm+lr+ref,head,head+lr,head+lr+ref,fuse+lr+ref,fuse-all+lr+ref --occlude 10,20,30,40"
  "native_w160|--profile w160 --precision int8,f32 --pathway native"
  "native_occlusion_w160|--profile w160 --precision int8 --readout head,head+lr,head+lr+ref,fuse-census+lr+ref --occlude 10,20,30,40 --pathway native"
  "native_nuisance_w160|--profile w160 --precision int8 --readout head+lr+ref,fuse-census+lr+ref --nuisance $nuisances --pathway native"
  "native_nuisance_w320|--profile w320 --max-cols 16 --precision int8 --readout head+lr+ref,fuse-census+lr+ref --nuisance $nuisances --pathway native"
  "native_w320|--profile w320 --max-cols 16 --precision int8 --pathway native"
  "native_f32_w320|--profile w320 --max-cols 16 --precision f32 --pathway native"
)

selected=("$@")
known=" ${runs[*]%%|*} int8_compare_w160 heldout_w160 heldout_w320 "
for w in "${selected[@]}"; do
  if [[ "$known" != *" $w "* ]]; then
    echo "error: measure_tables.sh: unknown run '$w' (known:$known)" >&2
    exit 2
  fi
done
wanted() {
  [[ ${#selected[@]} -eq 0 ]] && return 0
  for w in "${selected[@]}"; do [[ "$w" == "$1" ]] && return 0; done
  return 1
}

cargo build -q --release --locked -p bino-host --bin bino
bino="$CARGO_TARGET_DIR/release/bino"

for run in "${runs[@]}"; do
  name="${run%%|*}"
  read -r -a args <<<"${run#*|}"
  wanted "$name" || continue
  printf '\n== %s: bino eval %s\n' "$name" "${args[*]}"
  start=$SECONDS
  "$bino" eval --data "$data" --split eval "${args[@]}" --json "$metrics/$name.json"
  printf '== %s: %d s\n' "$name" $((SECONDS - start))
done

# The held-out labeled train pairs (bino_train.labeled.LABELED_HOLDOUT: validation, no head trains
# on them, never the eval split), resized by bino_train.labeled_folder and scored like the eval
# split: the readouts every recipe was chosen with, StereoSGBM in the same run.
for width in 160 320; do
  name="heldout_w$width"
  wanted "$name" || continue
  printf '\n== %s: labeled_folder --width %d, bino eval --split val\n' "$name" "$width"
  start=$SECONDS
  folder="$(mktemp -d)"
  (cd train && "$BINO_VENV/bin/python" -W ignore -m bino_train.labeled_folder --width "$width" \
    --out "$folder" --data "$data")
  cols=$((width == 320 ? 16 : 10))
  "$bino" eval --data "$folder" --split val --profile native --precision int8 --max-cols "$cols" \
    --readout census+lr+ref,sgm+lr+ref,head+lr+ref,fuse+lr+ref,fuse-all+lr+ref --json "$metrics/$name.json"
  # The board's readout (the native pathway) on the same pairs.
  "$bino" eval --data "$folder" --split val --profile native --precision int8 --pathway native \
    --readout head+lr+ref,fuse-census+lr+ref --json "$metrics/native_$name.json"
  rm -rf "$folder"
  printf '== %s: %d s\n' "$name" $((SECONDS - start))
done
if wanted int8_compare_w160; then
  printf '\n== int8_compare_w160: bino compare\n'
  start=$SECONDS
  "$bino" compare --data "$data" --split eval --profile w160 --onnx weights/bino_encoder.onnx \
    --blob weights/bino_int8.bin --head weights/bino_head.onnx --pathway native \
    --json "$metrics/int8_compare_w160.json"
  printf '== int8_compare_w160: %d s\n' $((SECONDS - start))
fi
