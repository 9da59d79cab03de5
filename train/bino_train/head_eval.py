"""The shared head scored on the eval split by EVAL.md, next to StereoSGBM from the same run.

    python -m bino_train.head_eval --encoder runs/PRE/last.pt --head runs/HEAD/last.pt
    python -m bino_train.head_eval --random-init-seed 0 --head runs/HEAD/last.pt --profile w160

Descriptors are computed exactly as in probe.py (each view resized to the profile, 48-row
overlapping bands stitched for taller images); the head runs on the whole stitched map (it is
convolutional in rows and columns). Head disparity in patch columns x 4 = px on the token grid,
bilinearly upsampled to pixels, then epe / bad1tok / bad2 per pair and the mean over pairs.
The no-linkage probe (cosine WTA, 10 columns) on the same descriptors is reported alongside.
The head predicts every pixel: density 100. A native head (head.NativeHead) reads the phase maps
of one encoder pass on each pair instead (`pair_inputs`); it has no probe.

`head+lr` is the Rust CLI's readout of that name (`bino_host::readout`): the head's own
left-right check (the export head on the mirrored descriptor maps gives the right view's
disparity; the native head reads it from its own logits' diagonal, `diagonal_right`, with no
second encoder pass; a left cell is kept when the right cell it lands on reads the same
disparity within one column), and each rejected cell takes the disparity of the nearest kept
cell to its left, before upsampling.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .head import StereoHead, head_candidates, load_head, with_candidates
from .model import BinoEncoder
from .probe import (
    Gray,
    ProbeItem,
    encoder_describe,
    encoder_phase_maps,
    load_probe_set,
    mean_metrics,
    run_sgbm,
    score,
    similarity_volume,
    upsample_disparity,
    wta_subtoken,
)
from .profile import profile_width

PROBE_COLS = 10
"""The probe's default candidate count (probe.py)."""
LR_MAX_DIFF = 1.0
"""Left-right tolerance in patch columns (the CLI's default `--lr-max-diff`)."""


def consistent(left: np.ndarray, right: np.ndarray, max_diff: float = LR_MAX_DIFF) -> np.ndarray:
    """Left cells whose disparity `d` lands on a right cell `p - round(d)` inside the view that
    reads a disparity within `max_diff` of it (token grids in patch columns, `d >= 0`)."""
    rows, cols = left.shape
    target = np.arange(cols)[None, :] - np.floor(left + 0.5).astype(np.int64)
    inside = target >= 0
    landed = np.take_along_axis(right, np.clip(target, 0, cols - 1), axis=1)
    return inside & (np.abs(landed - left) <= max_diff)


def fill_rejected(disparity: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Each rejected cell takes the nearest kept value to its left (the first kept value for
    those before it); a row with nothing kept is 0 (`bino_core::lr::fill_rejected`)."""
    out = np.zeros_like(disparity)
    for r, (row, mask) in enumerate(zip(disparity, kept, strict=True)):
        if not mask.any():
            continue
        carried = row[int(np.argmax(mask))]
        for c, (value, ok) in enumerate(zip(row, mask, strict=True)):
            if ok:
                carried = value
            out[r, c] = carried
    return out


def soft_argmin(logits: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Disparity (candidates) of (D, T, P) logits over the valid candidates; 0 where none is."""
    masked = np.where(valid, logits, -np.inf)
    top = masked.max(axis=0, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    weights = np.where(valid, np.exp(masked - top), 0.0)
    total = weights.sum(axis=0)
    k = np.arange(logits.shape[0], dtype=np.float64)[:, None, None]
    moment = (weights * k).sum(axis=0)
    return np.where(total > 0, moment / np.maximum(total, 1e-300), 0.0).astype(np.float32)


def diagonal_right(logits: np.ndarray) -> np.ndarray:
    """The right view's disparity from the left view's logits (D, T, P), one pass: right cell
    q soft-argmins over k the logit of left cell q + k at k, for every k with q + k inside the
    row (`bino_core::model::head::right_view_row`, the native pathway's check)."""
    d, _, p = logits.shape
    diag = np.full(logits.shape, -np.inf, dtype=np.float64)
    valid = np.zeros(logits.shape, dtype=bool)
    for k in range(min(d, p)):
        diag[k, :, : p - k] = logits[k, :, k:]
        valid[k, :, : p - k] = True
    return soft_argmin(diag, valid)


HeadInputs = tuple[torch.Tensor, torch.Tensor]
"""The two maps a head reads, each (rows, cols, C): D(L), D(R) or the native phase maps."""


def mirror_descriptors(dl: torch.Tensor, dr: torch.Tensor) -> HeadInputs:
    """The export head's mirrored inputs: the descriptor maps swapped and flipped left-right."""
    return dr.flip(1), dl.flip(1)


def pair_inputs(
    encoder: BinoEncoder, pathway: str, left: Gray, right: Gray
) -> tuple[HeadInputs, HeadInputs]:
    """(inputs, mirrored inputs) of a head of `pathway` for one pair. Native: the phase maps of
    the encoder on (L, R) and on (mirror(R), mirror(L)); export: D(L), D(R) and their mirror."""
    if pathway == "native":
        mirrored = encoder_phase_maps(
            encoder, np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])
        )
        return encoder_phase_maps(encoder, left, right), mirrored
    dl, dr = encoder_describe(encoder)([left, right])
    return (dl, dr), mirror_descriptors(dl, dr)


def head_lr(
    head: StereoHead, inputs: HeadInputs, mirrored: HeadInputs
) -> tuple[np.ndarray, np.ndarray]:
    """(left disparity, kept mask) of the head and its left-right check: for a native head the
    right view read from its own logits (`diagonal_right`), for the export head the head on
    `mirrored` (the mirrored pair's inputs, `pair_inputs`), flipped back."""
    device = next(head.parameters()).device
    first, second = (t[None].to(device) for t in inputs)
    out = head(first, second)
    left = out.disparity[0].float().cpu().numpy()
    if head.cfg.pathway == "native":
        return left, consistent(left, diagonal_right(out.logits[0].double().cpu().numpy()))
    first, second = (t[None].to(device) for t in mirrored)
    right = head(first, second).disparity[0].float().cpu().numpy()[:, ::-1]
    return left, consistent(left, right)


@torch.no_grad()
def head_scores(
    encoder: BinoEncoder, head: StereoHead, items: Sequence[ProbeItem]
) -> tuple[list[dict[str, float]], list[dict[str, float]], list[dict[str, float]]]:
    """Per-pair EVAL.md metrics of the head, of head+lr and of the probe (export pathway only:
    a native head's list is empty), from one set of encoder outputs."""
    head = head.eval()
    pathway = head.cfg.pathway
    heads, checked, probes = [], [], []
    for item in items:
        inputs, mirrored = pair_inputs(encoder, pathway, item.left, item.right)
        left, kept = head_lr(head, inputs, mirrored)
        heads.append(score(upsample_disparity(left), item.gt, item.valid))
        checked.append(score(upsample_disparity(fill_rejected(left, kept)), item.gt, item.valid))
        if pathway == "export":
            probe = wta_subtoken(similarity_volume(*inputs, PROBE_COLS))
            probes.append(score(upsample_disparity(probe), item.gt, item.valid))
    return heads, checked, probes


def evaluate_head(
    encoder: BinoEncoder,
    head: StereoHead,
    data_dir: Path | None = None,
    profile: str = "w160",
    per_pair: bool = False,
) -> dict[str, Any]:
    """{"pathway", "head", "head+lr", "probe", "sgbm": metrics} (means over the eval pairs; the
    probe only on the export pathway, None on the native one)."""
    items = load_probe_set(data_dir, profile)
    # The candidates follow the view width, as in every bino command (head.head_candidates).
    head = with_candidates(head, head_candidates(profile_width(profile)))
    heads, checked, probes = head_scores(encoder, head, items)
    out: dict[str, Any] = {
        "profile": profile,
        "pairs": len(items),
        "pathway": head.cfg.pathway,
        "head_candidates": head.cfg.max_disp,
        "head": {**mean_metrics(heads), "density": 100.0},
        "head+lr": {**mean_metrics(checked), "density": 100.0},
        "probe": {**mean_metrics(probes), "density": 100.0} if probes else None,
        "sgbm": run_sgbm(items, profile_width(profile)),
    }
    if per_pair:
        out["per_pair"] = {
            it.pair_id: {"head": h, "head+lr": c}
            for it, h, c in zip(items, heads, checked, strict=True)
        }
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--encoder", type=Path, help="encoder checkpoint the head was trained on")
    source.add_argument("--random-init-seed", type=int, help="encoder at a seeded random init")
    parser.add_argument("--head", type=Path, required=True, help="head checkpoint")
    parser.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    parser.add_argument("--profile", default="w160", help="w160 or w320")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--per-pair", action="store_true", help="include per-pair head metrics")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    from .export import load_encoder, random_encoder
    from .head_train import EncoderSource, build_encoder, encoder_digest

    start = time.perf_counter()
    state = torch.load(args.head, map_location="cpu", weights_only=False)
    if args.encoder is not None:
        encoder = load_encoder(args.encoder)
        method = f"head {args.head} on encoder {args.encoder}"
    else:
        trained = EncoderSource(**state.get("encoder_source", {"kind": "random-init"}))
        # A random-init encoder is rebuilt with the config the head was trained on.
        if trained.kind == "random-init" and trained.seed == args.random_init_seed:
            encoder = build_encoder(trained)
        else:
            encoder = random_encoder(args.random_init_seed)
        method = f"head {args.head} on random-init encoder seed {args.random_init_seed}"
    trained_hash = state.get("encoder_source", {}).get("sha256", "")
    if trained_hash and trained_hash != encoder_digest(encoder):
        print("warning: this encoder is not the one the head was trained on", file=sys.stderr)
    head = load_head(args.head)
    result = evaluate_head(encoder, head, args.data, args.profile, args.per_pair)
    output: dict[str, Any] = {"method": method, "head_step": state.get("step"), **result}
    output["seconds"] = round(time.perf_counter() - start, 2)
    print(json.dumps(output, indent=1))


if __name__ == "__main__":
    main()
