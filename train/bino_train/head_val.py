"""Validation for head recipes, never on the eval split (issue 13: choose recipes elsewhere).

Two sets, both fixed for a run:
- held-out train pairs (`head_data.validation_pairs`, never trained on by the head) at w160,
  scored like EVAL.md (token disparity upsampled bilinearly, epe / bad1tok / bad2 per pair, mean
  over pairs) against StereoSGBM's pixels that pass its own checks and the sub-pixel left-right
  check (`head_data.consistent_sgbm`): agreement with confident SGBM, a proxy, not accuracy;
- synthetic crops with exact disparity (`head_data.synthetic_sample`, seeds apart from any
  training seed), scored in px on the labelled cells whose match lies inside the right crop
  (`head.supervised_cells`: the others have no candidate);
- the held-out labeled train pairs (`labeled.LABELED_HOLDOUT`, issue 40) at w160 and w320
  against their real ground truth, resized by the EVAL.md profile rule: `val_gt_w160`,
  `val_gt_w320`, the float head and head+lr (unrefined) with the candidates `bino eval` gives
  the width (`head.head_candidates`: 12 at w160, 16 at w320).

Encoder outputs are computed once (`ValidationSet.build`); scoring a head costs only the head.
A set is built for one pathway (`--pathway`): export heads read D(L), D(R); native heads the
phase maps of one pass on (L, R), and for their left-right check those of the pass on
(mirror(R), mirror(L)) (head_eval.pair_inputs).

    python -m bino_train.head_val --encoder E --heads runs/A/last.pt runs/B/last.pt
    python -m bino_train.head_val --encoder E --pathway native --heads runs/N/last.pt
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from .head import StereoHead, head_candidates, supervised_cells, with_candidates
from .head_data import (
    PATHWAYS,
    DataConfig,
    DescBatch,
    check_pathway,
    consistent_sgbm,
    encode,
    synthetic_sample,
    validation_pairs,
)
from .head_eval import HeadInputs, fill_rejected, head_lr, pair_inputs
from .labeled import heldout_labeled_pairs, load_checked_gt
from .model import BinoEncoder
from .pairs import load_gray
from .probe import CELL, mean_metrics, score, upsample_disparity
from .profile import resize_gt, resize_image, to_u8

VAL_WIDTH = 160
LABELED_WIDTHS = (160, 320)
"""Widths the held-out labeled pairs are scored at (the EVAL.md profiles)."""
SYNTHETIC_SEED = 1_000_003
"""Seeds of the synthetic validation crops: [SYNTHETIC_SEED, i], no training run uses it."""


@dataclass(frozen=True)
class HeldOutPair:
    pair_id: str
    inputs: HeadInputs
    """The head's two input maps (D(L), D(R), or the native phase maps)."""
    mirrored: HeadInputs
    """Those of the mirrored pair, for the head's left-right check."""
    disparity: NDArray[np.float32]
    valid: NDArray[np.bool_]


@dataclass(frozen=True)
class ValidationSet:
    pairs: list[HeldOutPair]
    synthetic: DescBatch
    pathway: str = "export"
    labeled: tuple[tuple[int, list[HeldOutPair]], ...] = ()
    """(width, held-out labeled pairs at that width with their real ground truth)."""

    @staticmethod
    @torch.no_grad()
    def build(
        encoder: BinoEncoder,
        data_dir: Path | None,
        data: DataConfig,
        synthetic_count: int = 96,
        device: torch.device | None = None,
        pathway: str = "export",
        width: int = VAL_WIDTH,
    ) -> ValidationSet:
        check_pathway(pathway)
        encoder.eval()
        pairs = []
        for pair in validation_pairs(data_dir):
            left = resize_image(load_gray(pair.left), width)
            right = resize_image(load_gray(pair.right), width)
            disparity, valid, _ = consistent_sgbm(to_u8(left), to_u8(right))
            inputs, mirrored = pair_inputs(encoder, pathway, left, right)
            pairs.append(HeldOutPair(pair.pair_id, inputs, mirrored, disparity, valid))
        samples = [
            synthetic_sample(np.random.default_rng([SYNTHETIC_SEED, i]), data)
            for i in range(synthetic_count)
        ]
        synthetic = encode(encoder, samples, device or torch.device("cpu"), pathway)
        labeled = tuple((w, labeled_items(encoder, data_dir, w, pathway)) for w in LABELED_WIDTHS)
        return ValidationSet(pairs, synthetic, pathway, labeled)

    @torch.no_grad()
    def score(self, head: StereoHead) -> dict[str, Any]:
        """{"val_sgbm": head vs confident SGBM, "val_sgbm_lr": head+lr, "val_synthetic"}."""
        if head.cfg.pathway != self.pathway:
            raise ValueError(
                f"a {head.cfg.pathway}-pathway head on a {self.pathway} validation set"
            )
        was_training = head.training
        head.eval()
        raw, checked = [], []
        for item in self.pairs:
            left, kept = head_lr(head, item.inputs, item.mirrored)
            raw.append(score(upsample_disparity(left), item.disparity, item.valid))
            filled = upsample_disparity(fill_rejected(left, kept))
            checked.append(score(filled, item.disparity, item.valid))
        device = next(head.parameters()).device
        syn = self.synthetic
        pred = head(syn.left.to(device), syn.right.to(device)).disparity.cpu()
        label = syn.label.cpu()
        # Cells whose true match lies outside the right crop have no candidate: not scored.
        known = supervised_cells(label, head.cfg.max_disp)
        err = (pred[known] - label[known]).abs() * CELL
        labeled: dict[str, Any] = {}
        for width, items in self.labeled:
            if items:
                labeled[f"val_gt_w{width}"] = score_items(head, items, head_candidates(width))
        head.train(was_training)
        return {
            **labeled,
            "val_sgbm": mean_metrics(raw) if raw else None,
            "val_sgbm_lr": mean_metrics(checked) if checked else None,
            "val_synthetic": {
                "epe": float(err.mean()),
                "bad1tok": float(100.0 * (err > CELL).float().mean()),
                "bad2": float(100.0 * (err > 2.0).float().mean()),
            },
            "val_pairs": len(self.pairs),
        }


def labeled_items(
    encoder: BinoEncoder, data_dir: Path | None, width: int, pathway: str
) -> list[HeldOutPair]:
    """The held-out labeled pairs at `width` (EVAL.md profile) with their real ground truth."""
    items = []
    for pair in heldout_labeled_pairs(data_dir):
        grays = [load_gray(pair.left), load_gray(pair.right)]
        disparity, valid = resize_gt(*load_checked_gt(pair, grays[0].shape), width)
        left, right = (resize_image(g, width) for g in grays)
        inputs, mirrored = pair_inputs(encoder, pathway, left, right)
        items.append(HeldOutPair(pair.pair_id, inputs, mirrored, disparity, valid))
    return items


@torch.no_grad()
def score_items(head: StereoHead, items: list[HeldOutPair], candidates: int) -> dict[str, Any]:
    """Mean EVAL.md metrics of the head and of head+lr (rejected cells filled from the left) on
    `items`, with `candidates` disparities, and head+lr's per pair."""
    head = with_candidates(head, candidates)
    raw, checked = [], []
    for item in items:
        left, kept = head_lr(head, item.inputs, item.mirrored)
        raw.append(score(upsample_disparity(left), item.disparity, item.valid))
        filled = upsample_disparity(fill_rejected(left, kept))
        checked.append(score(filled, item.disparity, item.valid))
    return {
        "head": mean_metrics(raw),
        "head_lr": mean_metrics(checked),
        "pairs": {item.pair_id: m for item, m in zip(items, checked, strict=True)},
    }


def main(argv: list[str] | None = None) -> None:
    """Score head checkpoints on the validation sets (one set of descriptors for all)."""
    import argparse
    import json

    from .export import load_encoder
    from .head import load_head

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--encoder", type=Path, required=True, help="encoder the heads were trained on")
    p.add_argument("--heads", type=Path, nargs="+", required=True, help="head checkpoints")
    p.add_argument("--pathway", choices=PATHWAYS, default="export", help="the heads' pathway")
    p.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--width", type=int, default=VAL_WIDTH, help="held-out pairs' width (px)")
    p.add_argument(
        "--max-disp",
        type=int,
        help="score each head with this many candidates (no weight depends on the count)",
    )
    args = p.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    encoder = load_encoder(args.encoder)
    heads = {str(path): load_head(path, args.max_disp) for path in args.heads}
    for name, head in heads.items():
        if head.cfg.pathway != args.pathway:
            p.error(
                f"{name} is a {head.cfg.pathway}-pathway head; pass --pathway {head.cfg.pathway}"
            )
    data = DataConfig(crop_h=48, crop_w=160, max_disp=next(iter(heads.values())).cfg.max_disp)
    val = ValidationSet.build(encoder, args.data, data, pathway=args.pathway, width=args.width)
    print(json.dumps({name: val.score(head) for name, head in heads.items()}, indent=1))


if __name__ == "__main__":
    main()
