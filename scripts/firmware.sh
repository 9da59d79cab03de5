#!/usr/bin/env bash
# Builds the BINO firmware for both Cortex-M boards and runs each under QEMU: first the kernel
# test firmware (src/bin/kernel-tests.rs: the assembly kernels against their references), then the band pair
# through the int8 pipeline on both pathways of the learned preset and a whole 160x120 frame
# through both presets (with --frame320 the M55 also the Alif E7's 320x240 frame), bit-identical to the host
# (the firmware exits non-zero otherwise),
# with executed-instruction counts per stage, and per instruction class for the cycle model of
# `bino budget` (firmware-sim/qemu-plugin/CYCLES.md), from the TCG plugin in firmware-sim/qemu-plugin/.
#
#   scripts/firmware.sh [--band full|small] [--out DIR] [--profile] [--kernels|--kernels-only]
#                       [--cmsis-nn DIR] [--core m55|m7] [--frame320]
#
#   --band full    one 48x160 band pair, the issue's target size (default; about 2 min of QEMU
#                  for the M55 and 1 min for the M7 on a 2-core EPYC VM)
#   --band small   a 48x32 band pair (the census run on the same band): the same code,
#                  bit-identity only, 20 s
#   --out DIR      where the results go (default out/firmware)
#   --profile      also a per-function instruction profile (<core>-profile.txt)
#   --kernels      also the per-kernel table (<core>-kernels.md: executed instructions per MAC of
#                  the encoder's GEMMs, assembly kernel against the portable reference, from the
#                  kernel test firmware's markers); --kernels-only skips the band pair
#   --frame320     the Cortex-M55 also runs both presets on the Alif E7's whole 320x240 frame
#                  with the options of that width (feature frame320: stages census320_* and
#                  frame320_*, refined digests checked against measured/host-frame-320x240.json;
#                  5.8G instructions, 3 to 5 min more QEMU time); the M7 skips it. The
#                  measurement (firmware-sim/measured) uses it, CI does not
#   --cmsis-nn DIR with --kernels: also builds CMSIS-NN from the checkout DIR (github
#                  ARM-software/CMSIS-NN; never committed) into a bench on the same shapes
#                  (firmware-sim/cmsis-nn/, Debian's gcc-arm-none-eabi -O3), counts it in the
#                  same plugin and puts its measured column into <core>-kernels.md
#
# Writes <out>/<core>.json (stages, instructions and their classes, arena, stack, digests, ELF sections) and
# <out>/<core>.log (the decoded defmt log) per core; `bino budget --firmware <out>` reports them.
# Installs what is missing first: qemu-system-arm (apt), defmt-print (cargo install), the Rust
# targets and llvm-tools.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

band=full out="out/firmware" want_profile=0 want_kernels=0 kernels_only=0 cores="m55 m7" cmsis_nn="" frame320=0
while [ $# -gt 0 ]; do
  case "$1" in
    --band) band="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --profile) want_profile=1; shift ;;
    --kernels) want_kernels=1; shift ;;
    --kernels-only) want_kernels=1; kernels_only=1; shift ;;
    --core) cores="$2"; shift 2 ;;
    --frame320) frame320=1; shift ;;
    --cmsis-nn) cmsis_nn="$(cd "$2" && pwd)"; want_kernels=1; shift 2 ;;
    -h|--help) sed -n '2,34p' "$0"; exit 0 ;;
    *) echo "unknown argument $1" >&2; exit 2 ;;
  esac
done
case "$band" in
  full) features=() ;;
  small) features=(--features small-band) ;;
  *) echo "--band must be full or small" >&2; exit 2 ;;
esac
mkdir -p "$out"
out="$(cd "$out" && pwd)"

# The firmware is its own workspace with its own target directory: sharing the host's would
# make each build wait on the other's lock.
export CARGO_TARGET_DIR="$BINO_CACHE/firmware-target"

# ---- what a fresh machine lacks
as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }
if ! command -v qemu-system-arm >/dev/null; then
  echo "installing qemu-system-arm"
  as_root apt-get update -q
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q qemu-system-arm
fi
if ! command -v defmt-print >/dev/null; then
  echo "installing defmt-print (a few minutes)"
  cargo install defmt-print --version 1.2.0 --locked
fi
installed="$(rustup target list --installed)"
for target in $THUMB_TARGETS; do
  grep -qx "$target" <<<"$installed" || rustup target add "$target"
done
rustup component list --installed | grep -q '^llvm-tools' || rustup component add llvm-tools
if [ -n "$cmsis_nn" ] && ! command -v arm-none-eabi-gcc >/dev/null; then
  echo "installing gcc-arm-none-eabi (for --cmsis-nn)"
  as_root apt-get update -q
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q gcc-arm-none-eabi libnewlib-arm-none-eabi
fi
llvm_bin="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"

# ---- the instruction-count plugin
plugin_dir="$BINO_CACHE/qemu-plugin"
plugin="$plugin_dir/libinsn_count.so"
src="firmware-sim/qemu-plugin/insn_count.c"
if [ ! -f "$plugin" ] || [ "$src" -nt "$plugin" ] || [ firmware-sim/qemu-plugin/qemu-plugin-v1.h -nt "$plugin" ] ||
  [ firmware-sim/qemu-plugin/classify.h -nt "$plugin" ]; then
  mkdir -p "$plugin_dir"
  cc -O2 -Wall -Wextra -Werror -shared -fPIC -fvisibility=hidden -o "$plugin" "$src"
fi
# The instruction classifier of the cycle model (classify.h) against known encodings (< 1 s).
cc -O1 -Wall -Wextra -Werror -o "$plugin_dir/classify_test" firmware-sim/qemu-plugin/classify_test.c
"$plugin_dir/classify_test"

# ---- format and lints of the firmware workspace (both targets)
(cd firmware-sim && cargo fmt --check)
for target in $THUMB_TARGETS; do
  (cd firmware-sim && cargo clippy --locked --release --target "$target" "${features[@]}" -- -D warnings)
done
# The E7 frame's code (the Cortex-M55's), linted whether or not this run measures it.
(cd firmware-sim && cargo clippy --locked --release --target thumbv8m.main-none-eabihf "${features[@]}" \
  --features frame320 -- -D warnings)

qemu_version="$(qemu-system-arm --version | head -1)"
status=0
for core in $cores; do
  case "$core" in
    m55) target=thumbv8m.main-none-eabihf machine=mps3-an547 cpu=cortex-m55 ;;
    m7) target=thumbv7em-none-eabihf machine=mps2-an500 cpu=cortex-m7 ;;
    *) echo "unknown core $core" >&2; exit 2 ;;
  esac
  core_features=("${features[@]}")
  if [ "$frame320" = 1 ] && [ "$core" = m55 ]; then
    core_features+=(--features frame320)
  fi
  echo "== firmware: $core ($machine, $band band${core_features[*]:+, ${core_features[*]}})"
  (cd firmware-sim && cargo build --locked --release --target "$target" "${core_features[@]}")
  # The kernel test firmware first: every assembly kernel against its reference, bit for bit.
  # It ends with the encoder's GEMMs between markers, counted by the plugin (for --kernels).
  kelf="$CARGO_TARGET_DIR/$target/release/kernel-tests"
  kmarks="$("$llvm_bin/llvm-nm" "$kelf" | awk '$3 ~ /^bino_mark_/ {
    n = substr($3, 11); if (n == "end") n = "outside"; printf ",mark=%s:0x%s", n, $1 }')"
  set +e
  qemu-system-arm -machine "$machine" -cpu "$cpu" -display none -monitor none -serial null \
    -semihosting-config enable=on,target=native \
    -plugin "$plugin,out=$out/$core-kernel-counts.tsv$kmarks" \
    -kernel "$kelf" | defmt-print -e "$kelf" | tee "$out/$core-kernel-tests.log"
  codes=("${PIPESTATUS[@]}")
  set -e
  if [ "${codes[0]}" != 0 ] || [ "${codes[1]}" != 0 ]; then
    echo "kernel tests $core: FAILED (QEMU exit ${codes[0]}; see $out/$core-kernel-tests.log)" >&2
    status=1
  fi
  cmsis_args=()
  if [ -n "$cmsis_nn" ]; then
    # CMSIS-NN on the same shapes, in the same plugin (firmware-sim/cmsis-nn/bench.c).
    celf="$BINO_CACHE/cmsis-nn-$core.elf"
    firmware-sim/cmsis-nn/build.sh "$cmsis_nn" "$core" "$celf"
    cmarks="$("$llvm_bin/llvm-nm" "$celf" | awk '$3 ~ /^bino_mark_/ {
      n = substr($3, 11); if (n == "end") n = "outside"; printf ",mark=%s:0x%s", n, $1 }')"
    qemu-system-arm -machine "$machine" -cpu "$cpu" -display none -monitor none -serial null \
      -semihosting-config enable=on,target=native \
      -plugin "$plugin,out=$out/$core-cmsis-nn-counts.tsv$cmarks" \
      -kernel "$celf" 2>&1 | tee "$out/$core-cmsis-nn.log" # semihosting's console is stderr
    cmsis_args=(--cmsis-log "$out/$core-cmsis-nn.log" --cmsis-counts "$out/$core-cmsis-nn-counts.tsv"
      --cmsis-commit "$(git -C "$cmsis_nn" rev-parse --short HEAD 2>/dev/null || echo unknown)")
  fi
  if [ "$want_kernels" = 1 ]; then
    python3 firmware-sim/qemu-plugin/kernels.py --core "$core" --log "$out/$core-kernel-tests.log" \
      --counts "$out/$core-kernel-counts.tsv" --out "$out/$core-kernels.md" "${cmsis_args[@]}"
    [ "$kernels_only" = 1 ] && continue
  fi
  elf="$CARGO_TARGET_DIR/$target/release/bino-firmware"
  marks="$("$llvm_bin/llvm-nm" "$elf" | awk '$3 ~ /^bino_mark_/ {
    n = substr($3, 11); if (n == "end") n = "outside"; printf ",mark=%s:0x%s", n, $1 }')"
  [ -n "$marks" ] || { echo "no bino_mark_ symbols in $elf" >&2; exit 1; }
  profile_args=() report_profile=()
  if [ "$want_profile" = 1 ]; then
    profile_args=(",profile=$out/$core-blocks.tsv")
    report_profile=(--profile "$out/$core-blocks.tsv" --profile-out "$out/$core-profile.txt")
  fi
  start=$(date +%s.%N)
  set +e
  # -icount shift=0: one executed instruction is 1 ns of virtual time, so the camera's SysTick
  # row interval (firmware-sim/src/camera.rs) is a fixed number of instructions and every count
  # repeats exactly; sleep=off skips the time the core waits for a row (WFI).
  qemu-system-arm -machine "$machine" -cpu "$cpu" -display none -monitor none -serial null \
    -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off \
    -plugin "$plugin,out=$out/$core-counts.tsv,classes=$out/$core-classes.tsv$marks$(printf %s "${profile_args[@]}")" \
    -kernel "$elf" | defmt-print -e "$elf" | tee "$out/$core.log"
  codes=("${PIPESTATUS[@]}")
  set -e
  end=$(date +%s.%N)
  wall=$(awk -v a="$start" -v b="$end" 'BEGIN { print b - a }')
  [ "${codes[1]}" = 0 ] || { echo "defmt-print failed (${codes[1]})" >&2; status=1; }
  if ! python3 firmware-sim/qemu-plugin/report.py --core "$core" --cpu "$cpu" --board "$machine" \
    --target "$target" --elf "$elf" --log "$out/$core.log" --counts "$out/$core-counts.tsv" \
    --classes "$out/$core-classes.tsv" --llvm-size "$llvm_bin/llvm-size" --llvm-nm "$llvm_bin/llvm-nm" --qemu "$qemu_version" \
    --wall "$wall" --exit-status "${codes[0]}" --out "$out/$core.json" "${report_profile[@]}"; then
    echo "firmware $core: FAILED (QEMU exit ${codes[0]}; see $out/$core.log)" >&2
    status=1
  else
    echo "firmware $core: outputs bit-identical to the host; $(printf '%.0f' "$wall") s under QEMU; $out/$core.json"
  fi
  rm -f "$out/$core-blocks.tsv"
done
exit "$status"
