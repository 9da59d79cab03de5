"""The held-out labeled train pairs as a data folder `bino eval` scores (issue 40: choose every
recipe on real ground truth off the eval split).

For each pair of `labeled.LABELED_HOLDOUT` (MiddEval3-Q train pairs with ground truth that no
head trains on): both views resized to `--width` by the EVAL.md profile rule (area resize, height
round(H * P / W), bottom rows dropped to a multiple of 4; `profile.resize_image`), written as
8-bit PNGs, and the ground truth resized by the same rule (`profile.resize_gt`: nearest at pixel
centres, disparity times P / W) as a PFM with NaN where unknown, listed in a PAIRS.tsv with split
`val`. Scored with `--profile native` (the folder is already at the width), every score is the
EVAL.md protocol's at that profile, StereoSGBM recomputed in the same run:

    python -m bino_train.labeled_folder --width 160 --out /tmp/heldout160
    bino eval --data /tmp/heldout160 --split val --profile native --precision int8 \
        --readout head+lr+ref,sgm+lr+ref
    python -m bino_train.labeled_folder --width 320 --out /tmp/heldout320
    bino eval --data /tmp/heldout320 --split val --profile native --precision int8 --max-cols 16 \
        --readout sgm+lr+ref,head+lr+ref
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .folder_writer import errors_as_one_line, write_index, write_pair
from .labeled import LABELED_HOLDOUT, heldout_labeled_pairs, load_checked_gt
from .pairs import Pair, load_gray
from .profile import resize_gt, resize_image, to_u8


def write_folder(out: Path, width: int, data_dir: Path | None = None) -> list[str]:
    """Write the folder; returns the pair ids written (in the index's order)."""
    pairs = heldout_labeled_pairs(data_dir)
    if not pairs:
        raise ValueError(f"none of {', '.join(LABELED_HOLDOUT)} is a labeled train pair here")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for pair in pairs:
        views, gt = resized_pair(pair, width)
        rows.append(write_pair(out, pair.pair_id, pair.dataset, views, gt))
    write_index(out, rows)
    return [p.pair_id for p in pairs]


def resized_pair(pair: Pair, width: int) -> tuple[list[NDArray[np.uint8]], NDArray[np.float32]]:
    """A labeled pair as the folder holds it: both views resized to `width` px as 8-bit grey, and
    the left view's ground truth at that size (NaN unknown)."""
    grays = [load_gray(p) for p in (pair.left, pair.right)]
    disparity, valid = load_checked_gt(pair, grays[0].shape)
    views = [to_u8(resize_image(g, width)) for g in grays]
    disp, ok = resize_gt(disparity, valid, width)
    if disp.shape != views[0].shape:
        raise AssertionError(f"{pair.pair_id}: labels {disp.shape} vs view {views[0].shape}")
    return views, np.where(ok, disp, np.float32(np.nan)).astype(np.float32)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", type=Path, required=True, help="folder to write")
    p.add_argument("--width", type=int, required=True, help="width of the resized views (px)")
    p.add_argument("--data", type=Path, help="folder with PAIRS.tsv (default ../shared/data)")
    args = p.parse_args(argv)
    with errors_as_one_line("labeled_folder"):
        ids = write_folder(args.out, args.width, args.data)
    print(f"{len(ids)} held-out labeled pairs at {args.width} px in {args.out}: {' '.join(ids)}")


if __name__ == "__main__":
    main()
