#!/usr/bin/env bash
# Re-measures the host speed tables of docs/performance.md and the README on this machine:
# - `bino bench` (one 48x160 band; one thread against tract and onnxruntime, then every core)
#   with the fastest kernels and again held to AVX2 (--no-vnni) ->
#   train/checkpoints/metrics/bench_w160.json, bench_w160_avx2.json;
# - `bino run` on a 432x381 eval pair at w320 (hyperfine, each readout's pathway), on one
#   thread and on every core, with the fastest kernels and held to AVX2 (`--kernels avx2`), and
#   with BASELINE_BINO (an earlier build, optional) on one thread
#   -> train/checkpoints/metrics/run_timing_w320.json.
# About 10 minutes on 2 cores. Run it on a quiet machine: other work skews every figure.
#
#   scripts/measure_host.sh [bench] [run]      # both by default
#   BASELINE_BINO=/path/to/old/bino BASELINE_NAME=a207a57 scripts/measure_host.sh run
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

data="${BINO_DATA:-$BINO_ROOT/../shared/data}"
metrics=train/checkpoints/metrics
parts=("$@")
[ ${#parts[@]} -gt 0 ] || parts=(bench run)
for p in "${parts[@]}"; do
  case "$p" in bench | run) ;; *)
    echo "error: measure_host.sh: unknown part '$p' (bench, run)" >&2
    exit 2
    ;;
  esac
done

cargo build --release -p bino-host --bin bino
bino="$CARGO_TARGET_DIR/release/bino"

if [[ " ${parts[*]} " == *" bench "* ]]; then
  # Paths relative to the checkout, as the JSON records them.
  weights=(--onnx weights/bino_encoder.onnx --blob weights/bino_int8.bin)
  "$bino" bench "${weights[@]}" --runs 20 --json "$metrics/bench_w160.json"
  "$bino" bench "${weights[@]}" --runs 20 --no-vnni --json "$metrics/bench_w160_avx2.json"
fi

if [[ " ${parts[*]} " == *" run "* ]]; then
  command -v hyperfine >/dev/null || {
    echo "error: measure_host.sh: hyperfine is not installed (apt install hyperfine)" >&2
    exit 1
  }
  pair="$data/middlebury-2001-2003/scenes2001/barn1"
  [ -f "$pair/im2.ppm" ] || {
    echo "error: measure_host.sh: $pair/im2.ppm: no such file (../shared/data)" >&2
    exit 1
  }
  out="$(mktemp -d)"
  trap 'rm -rf "$out"' EXIT
  threads="$(nproc)"
  cmds=()
  names=()
  for pathway in census native export; do
    case "$pathway" in
      census) flags="" ;;
      *) flags="--pathway $pathway" ;;
    esac
    base="run --left $pair/im2.ppm --right $pair/im6.ppm --profile w320 $flags"
    for kernels in fastest avx2; do
      # The census readout runs no encoder: its kernels do not matter.
      [ "$pathway/$kernels" != census/avx2 ] || continue
      for t in 1 "$threads"; do
        names+=("$pathway|now|$t|$kernels")
        cmds+=("$bino --kernels $kernels $base --threads $t --out $out/$pathway-$kernels-$t")
      done
    done
    if [ -n "${BASELINE_BINO:-}" ]; then
      names+=("$pathway|${BASELINE_NAME:-baseline}|1|fastest")
      cmds+=("$BASELINE_BINO $base --out $out/$pathway-base")
    fi
  done
  hyperfine -N --warmup 1 --runs 10 --export-json "$out/hyperfine.json" "${cmds[@]}"
  python3 - "$out/hyperfine.json" "$metrics/run_timing_w320.json" "${names[@]}" <<'EOF'
import json, platform, subprocess, sys
src, dst, names = sys.argv[1], sys.argv[2], sys.argv[3:]
results = json.load(open(src))["results"]
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), None)
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
runs = []
for name, r in zip(names, results):
    pathway, build, threads, kernels = name.split("|")
    runs.append({"readout_pathway": pathway, "build": commit if build == "now" else build,
                 "threads": int(threads), "kernels": kernels, "median_s": r["median"], "min_s": r["min"],
                 "mean_s": r["mean"], "times_s": r["times"]})
out = {"tool": "scripts/measure_host.sh (hyperfine -N)", "pair": "mb2001_barn1 (432x381)",
       "profile": "w320", "cpu": cpu, "cores": int(subprocess.run(["nproc"], capture_output=True, text=True).stdout),
       "commit": commit, "runs": runs}
json.dump(out, open(dst, "w"), indent=2)
print(f"wrote {dst}")
EOF
fi
