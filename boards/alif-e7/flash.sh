#!/usr/bin/env bash
# The cargo runner of the Alif E7 build (`cargo run --release` in boards/alif-e7): writes the
# image to MRAM with Alif's Security Toolkit, then decodes the defmt log the board sends over
# RTT, read by a J-Link. probe-rs has no Ensemble target, hence these vendor tools. Not run by
# this repository's CI (there is no board); see README, "Flashing". Needs:
#   ALIF_SETOOLS   the unpacked Alif Security Toolkit (the directory with app-gen-toc)
#   JLinkRTTLogger SEGGER's J-Link software with Alif's device support (AE722F80F55D5_M55_HP)
#   defmt-print    cargo install defmt-print
set -euo pipefail
elf="$(realpath "$1")"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
: "${ALIF_SETOOLS:?set ALIF_SETOOLS to the Alif Security Toolkit directory (the one with app-gen-toc)}"
llvm_bin="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"

# The MRAM image: the ELF's loaded sections from 0x80000000 (the arena and .bss are not in it).
"$llvm_bin/llvm-objcopy" -O binary "$elf" "$ALIF_SETOOLS/build/images/bino-alif-e7.bin"
cp "$here/setools/bino-alif-e7.json" "$ALIF_SETOOLS/build/config/bino-alif-e7.json"
(cd "$ALIF_SETOOLS" && ./app-gen-toc -f build/config/bino-alif-e7.json && ./app-write-mram -p)

# RTT channel 0 into a file, decoded as it grows; Ctrl-C stops both.
log="$(mktemp --suffix=.rtt)"
JLinkRTTLogger -Device AE722F80F55D5_M55_HP -If SWD -Speed 4000 -RTTChannel 0 "$log" >/dev/null &
logger=$!
trap 'kill "$logger" 2>/dev/null; rm -f "$log"' EXIT
tail -f "$log" | defmt-print -e "$elf"
