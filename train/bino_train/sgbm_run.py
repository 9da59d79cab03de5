"""StereoSGBM with the EVAL.md settings on gray image pairs, for `bino eval`.

    python -m bino_train.sgbm_run --list JOBS.tsv

Each line of JOBS.tsv is `left.pgm <TAB> right.pgm <TAB> out.npy`: the pair as the Rust side
prepared it (already at the profile's resolution, 8-bit gray), and where to write SGBM's
left-view disparity in pixels as float32 `.npy`, with -1 where SGBM left a pixel invalid (its
internal left-right check or uniqueness test failed). Scoring stays on the Rust side, with
the same EVAL.md metric code as every other readout.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .head_data import sgbm_disparity


def run_job(left: Path, right: Path, out: Path) -> None:
    """SGBM on one pair; raises on unreadable or mismatched images."""
    views: list[NDArray[np.uint8]] = []
    for path in (left, right):
        view = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if view is None:
            raise SystemExit(f"error: cannot read {path}")
        views.append(np.asarray(view, dtype=np.uint8))
    if views[0].shape != views[1].shape:
        raise SystemExit(f"error: {left} and {right} differ in size")
    disparity, valid = sgbm_disparity(views[0], views[1])
    np.save(out, np.where(valid, disparity, np.float32(-1.0)).astype(np.float32))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--list", type=Path, required=True, help="TSV of left, right, out")
    args = parser.parse_args(argv)
    for line in args.list.read_text().splitlines():
        if line.strip():
            left, right, out = line.split("\t")
            run_job(Path(left), Path(right), Path(out))


if __name__ == "__main__":
    main()
