#!/usr/bin/env bash
# cargo runner: qemu-run.sh MACHINE CPU FIRMWARE.elf — runs the firmware under QEMU, decodes its
# defmt stream with defmt-print and exits with the firmware's semihosting exit status; -icount as
# scripts/firmware.sh (the camera's row interval is counted in instructions).
set -euo pipefail
machine="$1" cpu="$2" elf="$3"
set +e
qemu-system-arm -machine "$machine" -cpu "$cpu" -display none -monitor none -serial null \
  -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off -kernel "$elf" | defmt-print -e "$elf"
status=("${PIPESTATUS[@]}")
set -e
[ "${status[1]}" = 0 ] || echo "defmt-print failed (${status[1]})" >&2
exit "${status[0]}"
