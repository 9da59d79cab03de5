"""How much texture the flat regions of stereo pairs carry, and how much their views disagree.

    python -m bino_train.flat_texture --width 160 [--folder DIR ...] [--json OUT]

Issue 54 asked why the synthetic validation scenes (`synth_folder`) disagree with the real ones:
on them the census readout lost to the learned ones, on every real labeled set it wins. Per
pixel region, the census lost only on the textureless objects (epe 12.2 px against 4.7 at 160
px; 0.16 against 0.26 on the textured background). This measures what such regions hold in
real pairs: in the flat regions of a pair (the left view's gradient after a 3 px Gaussian below
half a grey level per pixel, eroded by 2 px, where the ground truth is known), the high-pass
(`synth_folder.high_pass`) of the left view and of the right view warped by the ground truth
split into the part both views share (sqrt of their mean product: surface micro-texture, which a
census of signs can match) and the part each has alone (the rms of their difference over sqrt 2:
noise and photometric mismatch), in grey levels.

Real pairs: the labeled train pairs outside `labeled.LABELED_HOLDOUT` (never the eval split),
resized to `--width` as `labeled_folder` resizes; `--folder`: any folder with ground truth
(`synth_folder` output), its `val` pairs as they are.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .labeled import LABELED_HOLDOUT, labeled_pairs
from .labeled_folder import resized_pair
from .pairs import load_gray, load_gt, load_pairs
from .profile import to_u8
from .synthetic import high_pass

Gray = NDArray[np.float32]
Mask = NDArray[np.bool_]

FLAT_GRADIENT = 0.5
"""Grey levels per pixel of the 3-px-smoothed left view below which a pixel is flat."""

MIN_PIXELS = 50
"""Flat pixels a pair needs to be counted."""


@dataclass(frozen=True)
class FlatTexture:
    shared: float
    """Rms of the micro-texture both views show, grey levels."""
    alone: float
    """Rms of what each view has alone (noise, photometric mismatch), grey levels."""
    flat_share: float
    """Fraction of the pair's pixels measured."""


def flat_mask(left: Gray, known: Mask) -> Mask:
    g = cv2.GaussianBlur(left, (0, 0), 3.0)
    gradient = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) / 8.0
    flat = (gradient < FLAT_GRADIENT) & known
    return cv2.erode(flat.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)


def measure(left: Gray, right: Gray, disparity: Gray) -> FlatTexture | None:
    """Grey-level views (0..255) and the left view's disparity (NaN unknown); None when fewer
    than MIN_PIXELS flat pixels."""
    h, w = left.shape
    xs = np.broadcast_to(np.arange(w, dtype=np.float32)[None, :], (h, w))
    ys = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w))
    known = np.isfinite(disparity)
    source = xs - np.where(known, disparity, 0.0).astype(np.float32)
    warped = cv2.remap(
        right, np.ascontiguousarray(source), np.ascontiguousarray(ys), cv2.INTER_LINEAR
    )
    inside = (source > 4) & (xs > 4) & (xs < w - 4)
    flat = flat_mask(left, known & inside)
    if int(flat.sum()) < MIN_PIXELS:
        return None
    a, b = high_pass(left)[flat], high_pass(np.asarray(warped, np.float32))[flat]
    shared = float(np.sqrt(max(float(np.mean(a * b)), 0.0)))
    alone = float(np.std(a - b) / np.sqrt(2.0))
    return FlatTexture(shared, alone, float(flat.mean()))


def mean(results: list[FlatTexture]) -> dict[str, float]:
    return {
        "pairs": len(results),
        **{k: float(np.mean([asdict(r)[k] for r in results])) for k in asdict(results[0])},
    }


def real_pairs(width: int, data_dir: Path | None) -> list[FlatTexture]:
    out = []
    for pair in labeled_pairs(data_dir):
        if pair.pair_id in LABELED_HOLDOUT:
            continue
        views, gt = resized_pair(pair, width)
        r = measure(views[0].astype(np.float32), views[1].astype(np.float32), gt)
        if r is not None:
            out.append(r)
    return out


def folder_pairs(folder: Path) -> list[FlatTexture]:
    out = []
    for pair in load_pairs(folder, "val"):
        left, right = (to_u8(load_gray(p)).astype(np.float32) for p in (pair.left, pair.right))
        disparity, valid = load_gt(pair)
        r = measure(left, right, np.where(valid, disparity, np.float32(np.nan)).astype(np.float32))
        if r is not None:
            out.append(r)
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--width", type=int, default=160, help="width the real pairs are resized to")
    p.add_argument("--data", type=Path, help="folder with PAIRS.tsv (default ../shared/data)")
    p.add_argument(
        "--folder", type=Path, action="append", default=[], help="a folder with ground truth"
    )
    p.add_argument("--json", type=Path, help="write the figures here")
    args = p.parse_args(argv)
    if args.width < 16:
        sys.exit(f"error: --width {args.width} is below 16 px")
    report: dict[str, dict[str, float]] = {}
    try:
        real = real_pairs(args.width, args.data)
        if not real:
            sys.exit("error: no labeled train pair outside the held-out ones has a flat region")
        report[f"labeled train pairs at {args.width} px"] = mean(real)
        for folder in args.folder:
            found = folder_pairs(folder)
            if not found:
                sys.exit(f"error: {folder}: no pair with ground truth and a flat region")
            report[str(folder)] = mean(found)
    except (OSError, ValueError) as err:
        sys.exit(f"error: {err}")
    for name, r in report.items():
        print(
            f"{name}: shared {r['shared']:.2f}, alone {r['alone']:.2f} grey levels "
            f"({r['pairs']:.0f} pairs, {100 * r['flat_share']:.1f} % flat)"
        )
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
