"""The held-out validation pairs written as a data folder for `bino eval --split val`."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bino_train.head_data import validation_pairs
from bino_train.pairs import load_gt, load_pairs
from bino_train.pfm import decode_pfm, encode_pfm
from bino_train.val_folder import write_folder
from tests.conftest import HEADER

SHIFT = 6


def _shifted_dataset(folder: Path) -> Path:
    """Four train pairs of one dataset (the last is held out), the right view the left shifted
    SHIFT px: a fronto-parallel plane SGBM finds everywhere it can match."""
    rng = np.random.default_rng(3)
    rows = ["\t".join(HEADER)]
    for i in range(4):
        texture = cv2.resize(rng.integers(0, 256, (30, 60), dtype=np.uint8), (240, 120))
        left, right = texture[:, :-SHIFT], texture[:, SHIFT:]
        names = [f"p{i}_l.png", f"p{i}_r.png"]
        for name, image in zip(names, (left, right), strict=True):
            cv2.imwrite(str(folder / name), image)
        h, w = left.shape
        rows.append("\t".join([f"p{i}", "train", "plane", *names, "", "", "", "", str(w), str(h)]))
    (folder / "PAIRS.tsv").write_text("\n".join(rows) + "\n")
    return folder


def test_pfm_encoding_round_trips_with_unknown_pixels() -> None:
    image = np.arange(12, dtype=np.float32).reshape(3, 4)
    image[1, 2] = np.nan
    back = decode_pfm(encode_pfm(image))
    np.testing.assert_array_equal(back, image)


def test_folder_holds_the_held_out_pairs_resized_with_confident_sgbm(tmp_path: Path) -> None:
    data = _shifted_dataset(tmp_path)
    out = tmp_path / "val"
    assert write_folder(out, 160, data) == 1
    (held,) = validation_pairs(data)
    (pair,) = load_pairs(out, "val")
    assert pair.pair_id == held.pair_id and pair.gt_format == "pfm"
    assert (pair.width, pair.height) == (160, 80)
    disparity, valid = load_gt(pair)
    assert disparity.shape == (80, 160)
    # The views shrink from 234 px to 160 and the shift with them; SGBM keeps most of the plane.
    assert valid.mean() > 0.5
    assert np.abs(disparity[valid] - SHIFT * 160 / (240 - SHIFT)).max() < 0.5
