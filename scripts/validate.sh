#!/usr/bin/env bash
# Scores a readout setting on every validation set, never the eval split: the held-out labeled
# train pairs (real ground truth), synthetic scenes with exact disparity (plain and with real
# textures) and the held-out train pairs against confident StereoSGBM (a proxy on textured
# pixels), at 160 and 320 px, int8, then prints one table (bino_train.validation_table).
#
#   scripts/validate.sh OUT [bino eval flags...]
#   scripts/validate.sh /tmp/v_base
#   scripts/validate.sh /tmp/v_p64 --sgm-p1 64 --sgm-p2 128
#   python -m bino_train.validation_table /tmp/v_p64 --baseline /tmp/v_base   # (in train/)
#
# The flags go to every `bino eval` (default readouts fuse+lr+ref,sgm+lr+ref,head+lr+ref, no
# StereoSGBM; name --readout to change them). 320 px runs search 16 candidates. The folders are
# written once into $BINO_CACHE/validation (VALIDATION_WIDTHS="160" for one width). About 5
# minutes for both widths on 2 cores.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"
if [[ $# -lt 1 || "$1" == -* ]]; then
  echo "usage: $0 OUT [bino eval flags...]" >&2
  exit 2
fi
out="$1"
shift
flags=("$@")
if [[ " ${flags[*]} " != *" --readout "* ]]; then
  flags+=(--readout fuse+lr+ref,sgm+lr+ref,head+lr+ref)
fi
data="${BINO_DATA:-$BINO_ROOT/../shared/data}"
folders="$BINO_CACHE/validation"
py() { (cd train && "$BINO_VENV/bin/python" -W ignore "$@"); }

# Writes one validation folder once; a half-written one (no PAIRS.tsv), or one older than the
# module that writes it (a changed generator), is written again.
folder() {
  local dir="$folders/$1$2" width="$2" module="train/${4//.//}.py"
  shift 2
  if [[ ! -f "$dir/PAIRS.tsv" || "$module" -nt "$dir/PAIRS.tsv" ]]; then
    rm -rf "$dir"
    py "$@" --width "$width" --out "$dir"
  fi
}

cargo build -q --release --locked -p bino-host --bin bino
bino="$CARGO_TARGET_DIR/release/bino"
mkdir -p "$out"
for width in ${VALIDATION_WIDTHS:-160 320}; do
  folder heldout "$width" -m bino_train.labeled_folder --data "$data"
  folder synth "$width" -m bino_train.synth_folder
  folder real "$width" -m bino_train.synth_folder --textures real --count 32 --data "$data"
  folder proxy "$width" -m bino_train.val_folder --data "$data"
  cols=()
  [[ "$width" == 320 ]] && cols=(--max-cols 16)
  for set in heldout synth real proxy; do
    printf '== %s%s: ' "$set" "$width"
    start=$SECONDS
    "$bino" eval --data "$folders/$set$width" --split val --profile native --precision int8 \
      --no-sgbm "${cols[@]}" "${flags[@]}" --json "$out/$set$width.json" >"$out/$set$width.log" 2>&1 ||
      { echo "failed; see $out/$set$width.log" >&2; tail -3 "$out/$set$width.log" >&2; exit 1; }
    printf '%d s\n' $((SECONDS - start))
  done
done
py -m bino_train.validation_table "$out"
