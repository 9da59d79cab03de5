#!/usr/bin/env python3
"""Per-kernel table of the kernel test firmware's bench: executed instructions per MAC.

Reads the decoded defmt log (`kernel-bench kernel=... macs=...` lines) and the plugin's counts
per marker (`bino_mark_<kernel>_fused`, `_reference`, ...) and writes a Markdown table. With
`--cmsis-log` and `--cmsis-counts` (the CMSIS-NN bench of `scripts/firmware.sh --cmsis-nn`, the
same shapes in the same plugin) the CMSIS-NN column is that measurement; without them it is
issue 16's figures on 960-row shapes.
"""

import argparse
import re
import sys
from pathlib import Path

# CMSIS-NN (commit 99f736a, arm-none-eabi-gcc 12.2 -O3), arm_nn_mat_mult_nt_t_s8 on the
# issue's 960-row shapes, requantisation and int8 store included (issue 16): the column when no
# CMSIS-NN bench was run.
CMSIS_NN = {
    ("m55", "qkv"): 0.281,
    ("m55", "mlp_up"): 0.281,
    ("m55", "mlp_down"): 0.201,
    ("m7", "qkv"): 1.709,
    ("m7", "mlp_up"): 1.709,
    ("m7", "mlp_down"): 1.478,
    # Q.K^T, 960x32 . 32x960 (no requantisation: int32 scores).
    ("m55", "scores"): 0.586,
    ("m7", "scores"): 2.653,
    # P.V, 960x960 . 960x32.
    ("m55", "pv"): 0.186,
    ("m7", "pv"): 1.436,
}
# CMSIS-NN's arm_softmax_s8 per element on a 960-long row, same harness (issue 16).
CMSIS_NN_PER_ELEMENT = {("m55", "softmax"): 298.0, ("m7", "softmax"): 287.0}
# What each per-element bench row measures.
ROW_LABELS = {
    "softmax": "softmax row (max, weights, sum)",
    "layernorm": "LayerNorm row (values, normalise, int8 out)",
    "residual": "residual add (carry + requantised delta, int8 out)",
}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--core", required=True)
    p.add_argument("--log", type=Path, required=True)
    p.add_argument("--counts", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--cmsis-log", type=Path, help="the CMSIS-NN bench's output")
    p.add_argument(
        "--cmsis-counts", type=Path, help="the plugin's counts of the CMSIS-NN bench"
    )
    p.add_argument(
        "--cmsis-commit", default="unknown", help="the CMSIS-NN checkout's commit"
    )
    args = p.parse_args()

    counts = read_counts(args.counts)
    cmsis_source = "issue 16's figures, 960-row shapes, not re-run"
    if args.cmsis_log and args.cmsis_counts:
        measured = cmsis_measured(args.cmsis_log, read_counts(args.cmsis_counts))
        CMSIS_NN.update(
            {(args.core, k): v for k, v in measured.items() if k != "softmax"}
        )
        if "softmax" in measured:
            CMSIS_NN_PER_ELEMENT[(args.core, "softmax")] = measured["softmax"]
        cmsis_source = f"measured here on the same shapes, CMSIS-NN {args.cmsis_commit}"
    rows = []
    pattern = re.compile(
        r"kernel-bench kernel=(\w+) m=(\d+) k=(\d+) n=(\d+) calls=(\d+) macs=(\d+) same=(\w+)"
    )
    for m in pattern.finditer(args.log.read_text()):
        kernel, mm, k, n, calls, macs, same = m.groups()
        if same != "true":
            print(
                f"kernels.py: {args.log}: kernel {kernel} differs from its reference",
                file=sys.stderr,
            )
            return 1
        if f"{kernel}_fast" in counts:
            variants = [("(int32 out)", f"{kernel}_fast", f"{kernel}_reference")]
        else:
            variants = [("fused (int8 out)", f"{kernel}_fused", f"{kernel}_reference")]
        if f"{kernel}_i32" in counts:
            variants.append(("int32 out", f"{kernel}_i32", f"{kernel}_i32_reference"))
        for label, fast, ref in variants:
            if fast not in counts or ref not in counts:
                print(
                    f"kernels.py: {args.counts}: no count for {fast} or {ref}",
                    file=sys.stderr,
                )
                return 1
            per_mac = counts[fast] / int(macs)
            ref_per_mac = counts[ref] / int(macs)
            cmsis = (
                CMSIS_NN.get((args.core, kernel))
                if label.startswith(("fused", "(int32"))
                else None
            )
            vs = f"{cmsis:.3f} ({per_mac / cmsis:.2f}x)" if cmsis else "-"
            rows.append(
                f"| {args.core} | {kernel} {label} | {calls} x {mm}x{k} . {k}x{n} | {int(macs):,} "
                f"| {counts[fast]:,} | **{per_mac:.3f}** | {ref_per_mac:.3f} | {vs} |"
            )
    rows += softmax_rows(args, counts)
    if not rows:
        print(f"kernels.py: {args.log}: no kernel-bench lines", file=sys.stderr)
        return 1
    header = (
        "| core | kernel | calls x shape | MACs | instructions | instr/MAC | portable reference instr/MAC "
        f"| CMSIS-NN instr/MAC (this/CMSIS; {cmsis_source}) |\n|---|---|---|---|---|---|---|---|\n"
    )
    args.out.write_text(header + "\n".join(rows) + "\n")
    print(args.out.read_text(), end="")
    return 0


def read_counts(path: Path) -> dict[str, int]:
    """The plugin's instructions per marker stage."""
    counts: dict[str, int] = {}
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        name, insns, _ = line.split("\t")
        counts[name] = int(insns)
    return counts


def cmsis_measured(log: Path, counts: dict[str, int]) -> dict[str, float]:
    """CMSIS-NN's instructions per MAC (per element for the softmax) from its bench."""
    text = log.read_text()
    if "cmsis-bench result=pass" not in text:
        print(f"kernels.py: {log}: the CMSIS-NN bench did not pass", file=sys.stderr)
        raise SystemExit(1)
    measured: dict[str, float] = {}
    gemm = re.compile(
        r"cmsis-bench kernel=(\w+) m=\d+ k=\d+ n=\d+ calls=\d+ macs=(\d+)"
    )
    rows = re.compile(r"cmsis-bench-rows kernel=(\w+) rows=\d+ n=\d+ elements=(\d+)")
    for pattern in (gemm, rows):
        for m in pattern.finditer(text):
            kernel, units = m.groups()
            if f"cmsis_{kernel}" not in counts:
                print(f"kernels.py: no count for cmsis_{kernel}", file=sys.stderr)
                raise SystemExit(1)
            measured[kernel] = counts[f"cmsis_{kernel}"] / int(units)
    return measured


def softmax_rows(args: argparse.Namespace, counts: dict[str, int]) -> list[str]:
    """Rows for the per-element benches (`kernel-bench-rows` lines: softmax, LayerNorm)."""
    rows = []
    pattern = re.compile(
        r"kernel-bench-rows kernel=(\w+) rows=(\d+) n=(\d+) elements=(\d+) same=(\w+)"
    )
    for m in pattern.finditer(args.log.read_text()):
        kernel, nrows, n, elements, same = m.groups()
        fast, ref = f"{kernel}_fast", f"{kernel}_reference"
        if same != "true" or fast not in counts or ref not in counts:
            print(
                f"kernels.py: {args.log}: {kernel} differs from its reference or was not counted",
                file=sys.stderr,
            )
            raise SystemExit(1)
        per = counts[fast] / int(elements)
        ref_per = counts[ref] / int(elements)
        cmsis = CMSIS_NN_PER_ELEMENT.get((args.core, kernel))
        vs = f"{cmsis:.0f} per element ({per / cmsis:.2f}x)" if cmsis else "-"
        rows.append(
            f"| {args.core} | {ROW_LABELS.get(kernel, kernel)} | {nrows} rows x {n} | {int(elements):,} elements "
            f"| {counts[fast]:,} | **{per:.2f}** per element | {ref_per:.2f} per element | {vs} |"
        )
    return rows


if __name__ == "__main__":
    sys.exit(main())
