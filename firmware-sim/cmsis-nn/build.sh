#!/usr/bin/env bash
# Builds the CMSIS-NN bench for one core: firmware-sim/cmsis-nn/build.sh CMSIS_NN_DIR m55|m7 OUT_ELF
# (Debian's gcc-arm-none-eabi 12.2 and newlib, -O3, as issue 16 measured CMSIS-NN).
set -euo pipefail
src="$1" core="$2" out="$3"
here="$(cd "$(dirname "$0")" && pwd)"
case "$core" in
  m55) cpu=(-mcpu=cortex-m55 -mfloat-abi=hard) ;;
  m7) cpu=(-mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard) ;;
  *) echo "build.sh: unknown core $core (m55 or m7)" >&2; exit 2 ;;
esac
for f in Include/arm_nnfunctions.h Source/NNSupportFunctions/arm_nn_mat_mult_nt_t_s8.c \
  Source/SoftmaxFunctions/arm_softmax_s8.c Source/SoftmaxFunctions/arm_nn_softmax_common_s8.c; do
  [ -f "$src/$f" ] || { echo "build.sh: $src is not a CMSIS-NN checkout (no $f)" >&2; exit 2; }
done
arm-none-eabi-gcc "${cpu[@]}" -mthumb -O3 -ffunction-sections -fdata-sections \
  -I"$src/Include" -T"$here/link.ld" -nostartfiles --specs=nano.specs --specs=nosys.specs \
  -Wl,--gc-sections -o "$out" \
  "$here/startup.c" "$here/bench.c" \
  "$src/Source/NNSupportFunctions/arm_nn_mat_mult_nt_t_s8.c" \
  "$src/Source/SoftmaxFunctions/arm_softmax_s8.c" \
  "$src/Source/SoftmaxFunctions/arm_nn_softmax_common_s8.c"
