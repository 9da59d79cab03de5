#!/usr/bin/env bash
# One GPU leg of a pretraining run, for the device machine (train/checkpoints/README.md,
# "Pretraining on a GPU"):
#
#   bash scripts/gpu_pretrain.sh MINUTES [BATCH_MULTIPLIER]     # e.g. 7 4
#
# Resumes train/checkpoints/$BINO_GPU_RUN/last.pt (default p7_short_blur; p7 finished its
# 30,000 pairs in session 37 and its resume point left the tree, so name a run that has one) exactly, trains bf16 on
# CUDA at BATCH_MULTIPLIER (default 4) times the run's batch on the same pair schedules, reading
# the train split from the carried pack train/gpu_pack (python -m bino_train.gpu_pack), for at
# most MINUTES minutes or until the run's --pairs target ($BINO_GPU_PAIRS, default 30000, p7's schedule), and
# writes into $OUT: teacher.pt and student.pt (fp16 weights, refreshed every minute, so a killed
# command still brings back the last minute's), log.jsonl (the run's whole log) and stdout.txt.
# No evaluation there (the pack holds no eval split). It fails (exit 3) when torch sees no GPU.
# A new run instead of a resume: BINO_GPU_NEW="pretrain recipe flags" (from scratch, no
# last.pt needed), e.g. BINO_GPU_NEW="--schedule-pairs 150000 --teacher-clean --head-bn".
# On CUDA the crops are cut by $BINO_GPU_WORKERS (default 8) processes (--data-workers).
#
# CPU smoke tests of this script (no GPU needed):
#   OUT=/tmp/o BINO_GPU_SMOKE=1 bash scripts/gpu_pretrain.sh 0.2 2  # tiny fresh model, seconds
#   OUT=/tmp/o BINO_GPU_DEVICE=cpu bash scripts/gpu_pretrain.sh 0.5 # the real checkpoint, on CPU
# Environment: BINO_PYTHON (default: the project venv's python if present, else python3),
# BINO_GPU_PACK (default train/gpu_pack), BINO_GPU_PRECISION (default bf16), BINO_THREADS.
set -euo pipefail

usage() {
  echo "usage: OUT=DIR $0 MINUTES [BATCH_MULTIPLIER]" >&2
  exit 2
}
[[ $# -ge 1 && $# -le 2 ]] || usage
minutes="$1"
multiplier="${2:-4}"
[[ "$minutes" =~ ^[0-9]+([.][0-9]+)?$ && "$multiplier" =~ ^[1-9][0-9]*$ ]] || usage
out="${OUT:-}"
[[ -n "$out" ]] || { echo "error: set OUT to the folder that comes back" >&2; exit 2; }

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv_python="${BINO_VENV:-$HOME/.cache/bino-edge/venv}/bin/python"
if [[ -z "${BINO_PYTHON:-}" && -x "$venv_python" ]]; then BINO_PYTHON="$venv_python"; fi
py="${BINO_PYTHON:-python3}"
run="${BINO_GPU_RUN:-p7_short_blur}"
ckpt="$root/train/checkpoints/$run"
pack="${BINO_GPU_PACK:-$root/train/gpu_pack}"
pairs="${BINO_GPU_PAIRS:-30000}"
precision="${BINO_GPU_PRECISION:-bf16}"
smoke="${BINO_GPU_SMOKE:-0}"
new_run="${BINO_GPU_NEW:-}"
workers="${BINO_GPU_WORKERS:-8}"
device="${BINO_GPU_DEVICE:-cuda}"
[[ "$smoke" == 1 ]] && device=cpu
export PYTHONUNBUFFERED=1

source_run="run $run"
[[ -n "$new_run" ]] && source_run="new run: $new_run"
echo "== gpu_pretrain: $minutes min, batch x$multiplier, device $device, $source_run, python $py"
[[ -f "$pack/PAIRS.tsv" ]] || {
  echo "error: no pack at $pack (python -m bino_train.gpu_pack --out gpu_pack, then carry it)" >&2
  exit 2
}
if [[ "$device" == cuda ]]; then
  if ! "$py" -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)'; then
    echo "error: torch ($py) sees no CUDA GPU; this script is for the GPU machine" >&2
    echo "       (BINO_GPU_DEVICE=cpu or BINO_GPU_SMOKE=1 run it on the CPU)" >&2
    exit 3
  fi
  nvidia-smi -L || true
fi

mkdir -p "$out"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
common=(--data "$pack" --device "$device" --precision "$precision" --no-eval
  --batch-multiplier "$multiplier" --minutes "$minutes" --checkpoint-minutes 1
  --weights-out "$out" --log-every 10 --threads "${BINO_THREADS:-0}")
if [[ "$device" == cuda ]]; then common+=(--chunk-tokens 131072); fi
if [[ "$device" == cuda || -n "${BINO_GPU_WORKERS:-}" ]]; then common+=(--data-workers "$workers"); fi
if [[ "$smoke" == 1 ]]; then
  train=(-m bino_train.pretrain --out "$work/run" --config small --batch 4
    --schedule-pairs 4000 --pairs "$pairs" "${common[@]}")
elif [[ -n "$new_run" ]]; then
  read -r -a recipe <<<"$new_run"
  train=(-m bino_train.pretrain --out "$work/run" --pairs "$pairs" "${recipe[@]}" "${common[@]}")
else
  [[ -f "$ckpt/last.pt" && -f "$ckpt/log.jsonl" ]] || {
    echo "error: no $ckpt/last.pt and log.jsonl to resume" >&2
    exit 2
  }
  mkdir -p "$work/run"
  cp "$ckpt/last.pt" "$ckpt/log.jsonl" "$work/run/"
  train=(-m bino_train.pretrain --out "$work/run" --resume --pairs "$pairs" "${common[@]}")
fi

set -o pipefail
(cd "$root/train" && "$py" -W ignore "${train[@]}") 2>&1 | tee "$out/stdout.txt"
for f in teacher.pt student.pt log.jsonl; do
  [[ -s "$out/$f" ]] || { echo "error: $out/$f was not written" >&2; exit 1; }
done
ls -l "$out"
echo "== gpu_pretrain: done; bring back teacher.pt, student.pt, log.jsonl (see checkpoints/README.md)"
