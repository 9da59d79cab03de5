"""Choose the pixel refinement's parameters on held-out train pairs, never on the eval split.

For each held-out train pair (`head_data.validation_pairs`) at a profile width, the float head
with its own left-right check and fill (head+lr, as `head_eval`) gives a token grid; the
integer refinement (`refine.refine_int`, bit-exact with `bino_core::refine`) turns it into
pixels for every parameter set asked for, and each result is scored like EVAL.md against
StereoSGBM's pixels that pass its own checks and the sub-pixel left-right check
(`head_data.consistent_sgbm`: agreement with confident SGBM, a proxy, not accuracy).

    python -m bino_train.refine_val --encoder E --head H --width 320 --search 2 4 6
    python -m bino_train.refine_val --encoder E --head H --nuisance blur --equalise

`--nuisance blur|noise|gain|gamma|occlude` degrades the right view first (a 5x5 box blur;
gaussian noise of sigma 8 grey levels, seeded; exposure `0.7 v + 20`; the tone curve
`255 (v / 255)^0.6`; mid-grey rectangles over 20 % of the area, seeded), like `bino eval
--nuisance` (the random draws are numpy's, not its SplitMix64), the ground truth still from the
clean pair;
`--equalise` adds each parameter set again with each row's census on sharpness-equalised views
(`bino_train.sharpness`).

prints one JSON object: per width and parameter set, the mean epe / bad1tok / bad2 and the
change of epe against the unrefined (bilinear) grid.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from .head import StereoHead
from .head_data import consistent_sgbm, validation_pairs
from .head_eval import fill_rejected, head_lr, pair_inputs
from .model import BinoEncoder
from .pairs import load_gray
from .probe import mean_metrics, score, upsample_disparity
from .profile import resize_image, to_u8
from .refine import RefineParams, keep_rejected, refine_int
from .sharpness import box, refine_equalised

NOISE_SIGMA = 8.0
"""Grey levels of `--nuisance noise` (bino eval's `NOISE_SIGMA`)."""

NUISANCES = ("none", "blur", "noise", "gain", "gamma", "occlude")
"""The right-view degradations `degrade` knows (bino eval's, and none)."""


def occlude(right: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """Mid-grey rectangles (each at most 1/5 of the width and height) until 20 % is covered."""
    out = right.copy()
    h, w = right.shape
    covered = np.zeros(right.shape, dtype=bool)
    while covered.mean() < 0.2:
        rw = int(rng.integers(max(w // 20, 1), max(w // 5, 1) + 1))
        rh = int(rng.integers(max(h // 20, 1), max(h // 5, 1) + 1))
        x, y = int(rng.integers(0, w - rw + 1)), int(rng.integers(0, h - rh + 1))
        out[y : y + rh, x : x + rw] = 128
        covered[y : y + rh, x : x + rw] = True
    return out


def degrade(right: NDArray[np.uint8], nuisance: str, seed: int) -> NDArray[np.uint8]:
    """The right view under `nuisance` (one of `NUISANCES`)."""
    values = right.astype(np.float64)
    if nuisance == "none":
        return right
    if nuisance == "blur":
        return box(right, 2)
    if nuisance == "noise":
        noise = np.random.default_rng(seed).normal(0.0, NOISE_SIGMA, right.shape)
        return np.clip(np.round(values + noise), 0, 255).astype(np.uint8)
    if nuisance == "gain":
        return np.clip(np.floor(0.7 * values + 20.0 + 0.5), 0, 255).astype(np.uint8)
    if nuisance == "gamma":
        return np.clip(np.floor(255.0 * (values / 255.0) ** 0.6 + 0.5), 0, 255).astype(np.uint8)
    if nuisance == "occlude":
        return occlude(right, np.random.default_rng(seed))
    raise ValueError(f"unknown nuisance {nuisance!r} ({', '.join(NUISANCES)})")


def to_q8(tokens: NDArray[np.float32]) -> NDArray[np.uint16]:
    """Patch-column disparities to the readouts' Q8 (rounded half up, saturated)."""
    return np.clip(np.floor(tokens.astype(np.float64) * 256.0 + 0.5), 0, 65535).astype(np.uint16)


@torch.no_grad()
def validate(
    encoder: BinoEncoder,
    head: StereoHead,
    width: int,
    params: list[RefineParams],
    data_dir: Path | None = None,
    nuisance: str = "none",
    equalised: bool = False,
) -> dict[str, Any]:
    """Mean metrics of head+lr unrefined and refined with each of `params` at `width` (and,
    if `equalised`, each again on sharpness-equalised views), the right view under `nuisance`."""
    encoder.eval()
    head.eval()
    unrefined: list[dict[str, float]] = []
    variants = [(p, False) for p in params] + ([(p, True) for p in params] if equalised else [])
    refined: list[list[dict[str, float]]] = [[] for _ in variants]
    pairs = validation_pairs(data_dir)
    for index, pair in enumerate(pairs):
        left_f = resize_image(load_gray(pair.left), width)
        right_f = resize_image(load_gray(pair.right), width)
        left, right = to_u8(left_f), to_u8(right_f)
        gt, valid, _ = consistent_sgbm(left, right)
        right = degrade(right, nuisance, seed=index)
        right_f = right.astype(np.float32) / np.float32(255.0)
        inputs, mirrored = pair_inputs(encoder, head.cfg.pathway, left_f, right_f)
        tokens, kept = head_lr(head, inputs, mirrored)
        filled = fill_rejected(tokens, kept)
        unrefined.append(score(upsample_disparity(filled), gt, valid))
        q8 = to_q8(filled)
        for out, (p, eq) in zip(refined, variants, strict=True):
            refine = refine_equalised if eq else refine_int
            pixels = keep_rejected(refine(left, right, q8, p), q8, kept).astype(
                np.float32
            ) / np.float32(256.0)
            out.append(score(pixels, gt, valid))
    base = mean_metrics(unrefined)
    rows = []
    for (p, eq), scores in zip(variants, refined, strict=True):
        m = mean_metrics(scores)
        change = m["epe"] / base["epe"] - 1.0
        rows.append({**asdict(p), "equalised": eq, **m, "epe_change": change})
    return {
        "width": width,
        "nuisance": nuisance,
        "pairs": len(pairs),
        "unrefined": base,
        "refined": rows,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--encoder", type=Path, required=True, help="encoder checkpoint")
    parser.add_argument("--head", type=Path, required=True, help="head checkpoint")
    parser.add_argument("--width", type=int, nargs="+", default=[160, 320], help="profile widths")
    parser.add_argument("--search", type=int, nargs="+", default=[2], help="search radii (px)")
    parser.add_argument("--lam", type=int, nargs="+", default=[50], help="lambda values")
    parser.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    parser.add_argument(
        "--nuisance",
        nargs="+",
        default=["none"],
        choices=NUISANCES,
        help="right-view nuisances, each scored in turn",
    )
    parser.add_argument(
        "--equalise", action="store_true", help="also refine sharpness-equalised views"
    )
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    from .export import load_encoder
    from .head import load_head

    params = [RefineParams(search=s, lam=lam) for s in args.search for lam in args.lam]
    for p in params:
        p.check()
    encoder = load_encoder(args.encoder)
    head = load_head(args.head)
    results = [
        validate(encoder, head, w, params, args.data, n, args.equalise)
        for w in args.width
        for n in args.nuisance
    ]
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
