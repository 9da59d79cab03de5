"""The no-linkage descriptor probe on the eval split (EVAL.md; paper section 3.6, first readout).

    python -m bino_train.probe --checkpoint runs/NAME/last.pt
    python -m bino_train.probe --random-init-seed 0
    python -m bino_train.probe --baseline window12      # also: window4, sgbm

Each view of a pair is resized to the profile (w160 by default) and described separately:
D(I) = phase-averaged tokens of the encoder run on (I, I), in 48-row overlapping bands for
taller images. The cost of left cell (r, p) at disparity k patch columns is the cosine between
D_L[r, p] and D_R[r, p - k], k = 0 .. max_cols - 1 (candidates outside the image excluded);
winner-take-all, a parabola through the best similarity and its neighbours for the sub-token
step, 4 px per patch column, bilinear upsampling to pixels; epe / bad1tok / bad2 per pair,
then the mean over pairs.

This module is the only reader of the eval split.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import Tensor

from .model import BinoEncoder
from .pairs import EVAL_SPLIT, load_gray, load_gt, load_pairs
from .profile import profile_width, resize_gt, resize_image, to_u8

Gray = NDArray[np.float32]
Describe = Callable[[Sequence[Gray]], list[Tensor]]
"""Images (H, W) -> descriptor maps (H/4, W/4, d), one per image."""

CELL = 4
BAND_TOKEN_ROWS = 12
BAND_STRIDE_TOKEN_ROWS = 8


@dataclass(frozen=True)
class Band:
    start: int
    rows: int
    keep_from: int
    keep_to: int


def band_plan(token_rows: int) -> list[Band]:
    """The bands of bino_core::band::BandPlan: starts spread evenly, cuts mid-overlap."""
    if token_rows <= BAND_TOKEN_ROWS:
        return [Band(0, token_rows, 0, token_rows)]
    span = token_rows - BAND_TOKEN_ROWS
    count = -(-span // BAND_STRIDE_TOKEN_ROWS) + 1
    starts = [i * span // (count - 1) for i in range(count)]
    cuts = [(starts[i] + starts[i + 1] + BAND_TOKEN_ROWS) // 2 for i in range(count - 1)]
    edges = [0, *cuts, token_rows]
    return [Band(s, BAND_TOKEN_ROWS, edges[i], edges[i + 1]) for i, s in enumerate(starts)]


BAND_BATCH = 2
"""Bands per forward: larger batches only add allocation cost on CPU (measured)."""


@torch.no_grad()
def encoder_descriptors(model: BinoEncoder, images: Sequence[Gray]) -> list[Tensor]:
    """D(I) (H/4, W/4, d) for each image, computed band by band (fp32)."""
    device = next(model.parameters()).device
    crops: list[Gray] = []
    plans: list[list[Band]] = []
    for image in images:
        h, w = image.shape
        if h % CELL or w % CELL:
            raise ValueError(f"image size {image.shape} is not a multiple of {CELL}")
        plan = band_plan(h // CELL)
        plans.append(plan)
        crops.extend(image[b.start * CELL : (b.start + b.rows) * CELL] for b in plan)
    descs: list[Tensor] = []
    i = 0
    while i < len(crops):
        # Up to BAND_BATCH consecutive bands of one shape go through one forward.
        j = i + 1
        while j < min(len(crops), i + BAND_BATCH) and crops[j].shape == crops[i].shape:
            j += 1
        batch = torch.from_numpy(np.stack(crops[i:j])[:, None]).to(device)
        descs.extend(model.descriptors(batch.expand(-1, 3, -1, -1)).float().cpu())
        i = j
    out, k = [], 0
    for plan in plans:
        parts = [
            descs[k + n][b.keep_from - b.start : b.keep_to - b.start] for n, b in enumerate(plan)
        ]
        out.append(torch.cat(parts, dim=0))
        k += len(plan)
    return out


@torch.no_grad()
def encoder_phase_maps(model: BinoEncoder, left: Gray, right: Gray) -> tuple[Tensor, Tensor]:
    """The native pathway's phase maps (H/4, W/4, d) of one pair: the encoder once on (L, R) per
    48-row band (the bands of `encoder_descriptors`), de-interleaved, stitched (fp32)."""
    if left.shape != right.shape:
        raise ValueError(f"left {left.shape} and right {right.shape} differ")
    h, w = left.shape
    if h % CELL or w % CELL:
        raise ValueError(f"image size {left.shape} is not a multiple of {CELL}")
    device = next(model.parameters()).device
    evens, odds = [], []
    for band in band_plan(h // CELL):
        rows = slice(band.start * CELL, (band.start + band.rows) * CELL)
        views = [
            torch.from_numpy(np.ascontiguousarray(v[rows]))[None, None].expand(-1, 3, -1, -1)
            for v in (left, right)
        ]
        even, odd = model.phase_maps(views[0].to(device), views[1].to(device))
        keep = slice(band.keep_from - band.start, band.keep_to - band.start)
        evens.append(even[0, keep].float().cpu())
        odds.append(odd[0, keep].float().cpu())
    return torch.cat(evens), torch.cat(odds)


def window_descriptors(images: Sequence[Gray], size: int) -> list[Tensor]:
    """Zero-mean, unit-norm size x size pixel window centred on each 4x4 cell (reflect padding)."""
    if size < CELL or (size - CELL) % 2:
        raise ValueError(f"window {size} must be >= {CELL} and differ from it by an even number")
    pad = (size - CELL) // 2
    out = []
    for image in images:
        h, w = image.shape
        padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
        x = torch.from_numpy(np.ascontiguousarray(padded))[None, None]
        win = F.unfold(x, kernel_size=size, stride=CELL)[0].T  # (T * P, size * size)
        win = win - win.mean(dim=1, keepdim=True)
        win = F.normalize(win, dim=1, eps=1e-6)
        out.append(win.reshape(h // CELL, w // CELL, size * size))
    return out


def similarity_volume(dl: Tensor, dr: Tensor, max_cols: int) -> Tensor:
    """(T, P, K) cosine of D_L[r, p] and D_R[r, p - k]; -inf where p - k < 0."""
    dl = F.normalize(dl.float(), dim=-1, eps=1e-8)
    dr = F.normalize(dr.float(), dim=-1, eps=1e-8)
    t, p, _ = dl.shape
    sims = torch.full((t, p, max_cols), float("-inf"))
    for k in range(min(max_cols, p)):
        sims[:, k:, k] = (dl[:, k:] * dr[:, : p - k]).sum(-1)
    return sims


def wta_subtoken(sims: Tensor) -> Tensor:
    """Winner-take-all disparity in patch columns with a parabola sub-token step in [-0.5, 0.5]."""
    best = sims.argmax(dim=-1)
    k = sims.shape[-1]
    at = sims.gather(-1, best[..., None])[..., 0]
    left = sims.gather(-1, (best - 1).clamp_min(0)[..., None])[..., 0]
    right = sims.gather(-1, (best + 1).clamp_max(k - 1)[..., None])[..., 0]
    inside = (best > 0) & (best < k - 1) & torch.isfinite(left) & torch.isfinite(right)
    denom = left - 2.0 * at + right
    ok = inside & (denom < 0)
    step = torch.where(ok, (left - right) / (2.0 * torch.where(ok, denom, -1.0)), 0.0)
    return best.float() + step.clamp(-0.5, 0.5)


def upsample_disparity(tokens: Tensor | NDArray[np.float32]) -> NDArray[np.float32]:
    """Token-grid disparity in patch columns -> per-pixel disparity in pixels, bilinear."""
    grid = np.asarray(tokens, dtype=np.float32) * np.float32(CELL)
    t, p = grid.shape
    return np.asarray(cv2.resize(grid, (p * CELL, t * CELL), interpolation=cv2.INTER_LINEAR))


def score(
    pred: NDArray[np.float32], gt: NDArray[np.float32], valid: NDArray[np.bool_]
) -> dict[str, float]:
    """EVAL.md metrics of one pair over ground-truth-valid pixels."""
    err = np.abs(pred[valid] - gt[valid])
    return {
        "epe": float(err.mean()),
        "bad1tok": float(100.0 * (err > 4.0).mean()),
        "bad2": float(100.0 * (err > 2.0).mean()),
    }


@dataclass(frozen=True)
class ProbeItem:
    pair_id: str
    left: Gray
    right: Gray
    gt: NDArray[np.float32]
    valid: NDArray[np.bool_]


def load_probe_set(data_dir: Path | None = None, profile: str = "w160") -> list[ProbeItem]:
    """The eval split at a profile; ground truth already resized (EVAL.md)."""
    width = profile_width(profile)
    items = []
    for pair in load_pairs(data_dir, EVAL_SPLIT):
        left = resize_image(load_gray(pair.left), width)
        right = resize_image(load_gray(pair.right), width)
        disparity, valid = load_gt(pair)
        gt, gt_valid = resize_gt(disparity, valid, width)
        if gt.shape != left.shape:
            raise ValueError(f"{pair.pair_id}: ground truth {gt.shape} vs image {left.shape}")
        items.append(ProbeItem(pair.pair_id, left, right, gt, gt_valid))
    if not items:
        raise ValueError(f"no {EVAL_SPLIT} pairs in {data_dir}")
    return items


def descriptor_disparity(describe: Describe, left: Gray, right: Gray, max_cols: int) -> Tensor:
    dl, dr = describe([left, right])
    return wta_subtoken(similarity_volume(dl, dr, max_cols))


def mean_metrics(per_pair: list[dict[str, float]]) -> dict[str, float]:
    return {key: float(np.mean([m[key] for m in per_pair])) for key in per_pair[0]}


def probe_scores(
    describe: Describe, items: Sequence[ProbeItem], max_cols: int = 10
) -> list[dict[str, float]]:
    """EVAL.md metrics of each pair (WTA leaves no pixel invalid: density 100)."""
    scores = []
    for item in items:
        disp = upsample_disparity(descriptor_disparity(describe, item.left, item.right, max_cols))
        scores.append(score(disp, item.gt, item.valid))
    return scores


def run_probe(
    describe: Describe, items: Sequence[ProbeItem], max_cols: int = 10
) -> dict[str, float]:
    """Mean metrics over pairs."""
    return {**mean_metrics(probe_scores(describe, items, max_cols)), "density": 100.0}


def fill_invalid(disparity: NDArray[np.float32], valid: NDArray[np.bool_]) -> NDArray[np.float32]:
    """EVAL.md fill: carry the last valid value to the right; leading gaps take the first one."""
    out = disparity.copy()
    for y in range(out.shape[0]):
        cols = np.flatnonzero(valid[y])
        if cols.size == 0:
            out[y] = 0.0
            continue
        idx = np.maximum.accumulate(np.where(valid[y], np.arange(out.shape[1]), -1))
        idx[idx < 0] = cols[0]
        out[y] = disparity[y, idx]
    return out


def run_sgbm(items: Sequence[ProbeItem], width: int) -> dict[str, float]:
    """OpenCV StereoSGBM with the EVAL.md settings, on the same grayscale profile images."""
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=32 * width // 160,
        blockSize=5,
        P1=8 * 3 * 25,
        P2=32 * 3 * 25,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=0,
        speckleRange=0,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )
    per_pair, density = [], []
    for item in items:
        views = [to_u8(v) for v in (item.left, item.right)]
        raw = sgbm.compute(views[0], views[1]).astype(np.float32) / 16.0
        valid = raw >= 0
        density.append(100.0 * float(valid[item.valid].mean()))  # over GT-valid pixels
        per_pair.append(score(fill_invalid(raw, valid), item.gt, item.valid))
    return {**mean_metrics(per_pair), "density": float(np.mean(density))}


def encoder_describe(model: BinoEncoder) -> Describe:
    model.eval()
    return lambda images: encoder_descriptors(model, images)


def describe_from_args(
    baseline: str | None, checkpoint: Path | None, seed: int | None
) -> tuple[Describe, str]:
    """The descriptor function a CLI asked for (windowN baseline, checkpoint or random init),
    and its name for the report."""
    from .export import load_encoder, random_encoder  # export pulls in onnx; only CLIs need it

    if baseline is not None:
        if not baseline.startswith("window"):
            sys.exit(f"error: unknown baseline {baseline!r}")
        size = int(baseline.removeprefix("window"))
        return (lambda images: window_descriptors(images, size)), baseline
    if checkpoint is not None:
        return encoder_describe(load_encoder(checkpoint)), f"checkpoint {checkpoint}"
    return encoder_describe(random_encoder(seed or 0)), f"random-init seed {seed}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--checkpoint", type=Path, help="checkpoint with config + encoder keys")
    source.add_argument("--random-init-seed", type=int, help="encoder at a seeded random init")
    source.add_argument("--baseline", help="window4, window12 (any windowN) or sgbm")
    parser.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    parser.add_argument("--profile", default="w160", help="w160 or w320")
    parser.add_argument("--max-cols", type=int, default=10, help="disparity candidates (columns)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--per-pair", action="store_true", help="include per-pair metrics")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    start = time.perf_counter()
    items = load_probe_set(args.data, args.profile)
    per_pair: dict[str, dict[str, float]] = {}
    if args.baseline == "sgbm":
        result = run_sgbm(items, profile_width(args.profile))
        method = "sgbm"
    else:
        describe, method = describe_from_args(args.baseline, args.checkpoint, args.random_init_seed)
        scores = probe_scores(describe, items, args.max_cols)
        result = {**mean_metrics(scores), "density": 100.0}
        if args.per_pair:
            per_pair = {it.pair_id: m for it, m in zip(items, scores, strict=True)}
    output: dict[str, object] = {"method": method, "profile": args.profile, "pairs": len(items)}
    output.update(result)
    if args.per_pair and per_pair:
        output["per_pair"] = per_pair
    output["seconds"] = round(time.perf_counter() - start, 2)
    print(json.dumps(output, indent=1))


if __name__ == "__main__":
    main()
