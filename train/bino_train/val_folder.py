"""The held-out validation pairs as a data folder `bino eval` scores (issue 13: choose the Rust
readouts' settings, such as the SGM penalties, off the eval split).

For each of `head_data.validation_pairs` (train-split pairs no head is trained on): both views
resized to `--width` as `head_val` resizes them, written as 8-bit PNGs, and as ground truth the
StereoSGBM pixels that pass its own checks and the sub-pixel left-right check
(`head_data.consistent_sgbm`; NaN elsewhere, PFM), listed in a PAIRS.tsv with split `val`.
The scores are agreement with confident SGBM on textured pixels, a proxy, not accuracy: the
same proxy as `head_val`'s real pairs.

    python -m bino_train.val_folder --width 320 --out /tmp/val320
    bino eval --data /tmp/val320 --split val --profile native --precision int8 --no-sgbm ...
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from .folder_writer import errors_as_one_line, write_index, write_pair
from .head_data import consistent_sgbm, validation_pairs
from .pairs import load_gray
from .profile import resize_image, to_u8


def write_folder(out: Path, width: int, data_dir: Path | None = None) -> int:
    """Write the folder; returns the number of pairs."""
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for pair in validation_pairs(data_dir):
        views = [to_u8(resize_image(load_gray(p), width)) for p in (pair.left, pair.right)]
        disparity, valid, _ = consistent_sgbm(views[0], views[1])
        gt = np.where(valid, disparity, np.float32(np.nan))
        rows.append(write_pair(out, pair.pair_id, pair.dataset, views, gt))
    write_index(out, rows)
    return len(rows)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", type=Path, required=True, help="folder to write")
    p.add_argument("--width", type=int, required=True, help="width of the resized views (px)")
    p.add_argument("--data", type=Path, help="folder with PAIRS.tsv (default ../shared/data)")
    args = p.parse_args(argv)
    with errors_as_one_line("val_folder"):
        count = write_folder(args.out, args.width, args.data)
    print(f"{count} validation pairs at {args.width} px in {args.out}")


if __name__ == "__main__":
    main()
