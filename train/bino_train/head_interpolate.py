"""A head between two checkpoints of the same architecture: every weight (1 - alpha) * start +
alpha * end (weight-space interpolation of a fine-tuned model with its start, as WiSE-FT does).

    python -m bino_train.head_interpolate --start checkpoints/hnat_p7/last.pt \\
        --end checkpoints/hgt40nat_p7/last.pt --alpha 0.5 --out runs/hgt40nat_p7_mid/last.pt

The shipped native head is such a midpoint: the head trained on ground truth (`end`) gained at
w160 and on the synthetic folders but lost on the held-out labeled pairs at w320, and the
midpoint beats its start on every validation set (`experiments.json`, hgt40nat_p7_mid). The
output keeps `end`'s configuration and run metadata (so the manifest and `head --checkpoint`
read it like a run's `last.pt`), drops the optimiser state, and records both sources.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch


def interpolate_states(
    start: dict[str, torch.Tensor], end: dict[str, torch.Tensor], alpha: float
) -> dict[str, torch.Tensor]:
    """(1 - alpha) * start + alpha * end for every floating-point tensor; other tensors (counters)
    are `end`'s. The two must hold the same names and shapes."""
    if start.keys() != end.keys():
        missing = sorted(start.keys() ^ end.keys())
        raise ValueError(f"the heads differ in their tensors: {missing[:4]}")
    out = {}
    for name, b in end.items():
        a = start[name]
        if a.shape != b.shape:
            raise ValueError(f"{name}: shapes {tuple(a.shape)} and {tuple(b.shape)} differ")
        out[name] = (
            (1 - alpha) * a.float() + alpha * b.float() if b.is_floating_point() else b.clone()
        )
    return out


def interpolate_checkpoints(start: Path, end: Path, alpha: float) -> dict[str, Any]:
    """`end`'s checkpoint with its head replaced by the interpolation and no optimiser state."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha {alpha} is outside [0, 1]")
    a = torch.load(start, map_location="cpu", weights_only=False)
    b = torch.load(end, map_location="cpu", weights_only=False)
    config_a = {k: v for k, v in a["head_config"].items() if k != "max_disp"}
    config_b = {k: v for k, v in b["head_config"].items() if k != "max_disp"}
    if config_a != config_b:
        raise ValueError(f"{start} and {end} are different head architectures")
    out = {k: v for k, v in b.items() if k != "optimizer"}
    out["head"] = interpolate_states(a["head"], b["head"], alpha)
    out["interpolated"] = {"start": str(start), "end": str(end), "alpha": alpha}
    return out


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--start", type=Path, required=True, help="checkpoint at alpha 0")
    p.add_argument("--end", type=Path, required=True, help="checkpoint at alpha 1")
    p.add_argument("--alpha", type=float, default=0.5)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    try:
        state = interpolate_checkpoints(args.start, args.end, args.alpha)
    except (OSError, ValueError) as e:
        raise SystemExit(f"error: {e}") from e
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, args.out)
    print(f"wrote {args.out}: {args.alpha:g} of the way from {args.start} to {args.end}")


if __name__ == "__main__":
    main()
