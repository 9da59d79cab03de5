"""Left-right checks of a head compared on labeled folders: which cells each keeps, and the
filled map's accuracy (token grid upsampled bilinearly, EVAL.md metrics, mean over pairs).

    python -m bino_train.check_variants --encoder E --head H --folders /tmp/heldout160 /tmp/synth160

Checks (each keeps a left cell or rejects it; rejected cells take the nearest kept value to
their left, `head_eval.fill_rejected`, as `+lr` does):
- `none`: the head alone;
- `mirrored`: the head on the mirrored pair gives the right view (a second encoder pass on the
  native pathway);
- `diagonal`: the right view read from the left head's own logits, right cell q taking the
  soft-argmin over k of logit(q + k, k) (candidates with q + k outside the row excluded): one
  pass, the classical way SGM gets its right map (`head_eval.diagonal_right`; the native
  pathway's `head+lr`);
- `confident`: cells whose softmax peak is at least a threshold;
- `diagonal+confident`: both.

Folders are `labeled_folder` / `synth_folder` outputs (split `val`, ground truth at the views'
width). Never the eval split: the check is chosen here.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from .folder_scoring import per_variant, run_cli
from .head import StereoHead
from .head_eval import LR_MAX_DIFF, consistent, diagonal_right, fill_rejected, pair_inputs
from .model import BinoEncoder
from .pairs import load_gray, load_gt, load_pairs
from .probe import score, upsample_disparity

Grid = NDArray[np.float32]
Mask = NDArray[np.bool_]

CONFIDENCE_THRESHOLDS = (0.3, 0.5)
"""Softmax peaks tried by the `confident` check."""


def checks(
    left: Grid, right_mirrored: Grid, logits: Grid, confidence: Grid
) -> dict[str, Mask | None]:
    """Each check's kept mask (None: keep everything)."""
    diagonal = consistent(left, diagonal_right(logits), LR_MAX_DIFF)
    out: dict[str, Mask | None] = {
        "none": None,
        "mirrored": consistent(left, right_mirrored, LR_MAX_DIFF),
        "diagonal": diagonal,
    }
    for tau in CONFIDENCE_THRESHOLDS:
        out[f"confident{tau}"] = confidence >= tau
        out[f"diagonal+confident{tau}"] = diagonal & (confidence >= tau)
    return out


@torch.no_grad()
def score_folder(encoder: BinoEncoder, head: StereoHead, folder: Path) -> dict[str, dict[str, Any]]:
    """{check: {"mean": metrics + kept %, "pairs": {pair: metrics}}} over `folder`'s val pairs."""
    pathway = head.cfg.pathway
    per: dict[str, list[dict[str, float]]] = {}
    names: list[str] = []
    for pair in load_pairs(folder, "val"):
        left_px, right_px = load_gray(pair.left), load_gray(pair.right)
        gt, valid = load_gt(pair)
        inputs, mirrored = pair_inputs(encoder, pathway, left_px, right_px)
        out = head(*(t[None] for t in inputs))
        left = out.disparity[0].float().numpy()
        logits = out.logits[0].double().numpy()
        confidence = out.confidence[0].float().numpy()
        right = head(*(t[None] for t in mirrored)).disparity[0].float().numpy()[:, ::-1]
        names.append(pair.pair_id)
        for name, kept in checks(left, np.ascontiguousarray(right), logits, confidence).items():
            filled = left if kept is None else fill_rejected(left, kept)
            metrics = score(upsample_disparity(filled), gt, valid)
            metrics["kept"] = 100.0 if kept is None else float(100.0 * kept.mean())
            per.setdefault(name, []).append(metrics)
    return per_variant(names, per)


def summary(m: dict[str, float]) -> str:
    """`epe / bad1tok (kept %)` of one check's mean metrics."""
    return f"{m['epe']:.3f} / {m['bad1tok']:.2f} (kept {m['kept']:.1f} %)"


def main(argv: Sequence[str] | None = None) -> None:
    run_cli(__doc__ or "", "head checkpoint", score_folder, argv, summary=summary)


if __name__ == "__main__":
    main()
