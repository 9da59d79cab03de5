"""The stereo pair index (`PAIRS.tsv`), image and ground-truth loading, and the split guard.

Every code path reads images through `load_gray`, so colour pairs become grayscale by one rule:
OpenCV's BGR2GRAY on the stored 8-bit pixels, then a division by 255.

The eval split is for scoring only (DATA.md). Training code gets its pairs from
`training_pairs`, which can only ever return `split == "train"` rows; asking for anything
else with `for_training=True` raises `SplitError`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .pfm import read_pfm

DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"
"""`../shared/data` relative to the repository root."""

INDEX_NAME = "PAIRS.tsv"
TRAIN_SPLIT = "train"
EVAL_SPLIT = "eval"
COLUMNS = ("pair_id split dataset left right gt gt_format gt_scale gt_invalid width height").split()
GT_DTYPES = {"pgm_u8": np.uint8, "png_u8": np.uint8, "png_u16": np.uint16}
"""The integer `gt_format`s and the pixel type each stores (KITTI's png_u16: `gt_scale` 256)."""
GT_FORMATS = (*GT_DTYPES, "pfm")
"""Every `gt_format`; `pfm` (Middlebury 2014, ETH3D) stores float32 pixels, non-finite = unknown."""


class SplitError(RuntimeError):
    """A training code path asked for pairs outside the train split."""


@dataclass(frozen=True)
class Pair:
    """One row of `PAIRS.tsv`, with its paths made absolute."""

    pair_id: str
    split: str
    dataset: str
    left: Path
    right: Path
    gt: Path | None
    gt_format: str
    gt_scale: float
    gt_invalid: int | None
    width: int
    height: int


def _parse_row(row: dict[str, str], folder: Path) -> Pair:
    gt = row["gt"].strip()
    return Pair(
        pair_id=row["pair_id"],
        split=row["split"],
        dataset=row["dataset"],
        left=folder / row["left"],
        right=folder / row["right"],
        gt=folder / gt if gt else None,
        gt_format=row["gt_format"],
        gt_scale=float(row["gt_scale"]) if row["gt_scale"].strip() else 1.0,
        gt_invalid=int(row["gt_invalid"]) if row["gt_invalid"].strip() else None,
        width=int(row["width"]),
        height=int(row["height"]),
    )


def load_pairs(
    data_dir: Path | None = None, split: str | None = None, *, for_training: bool = False
) -> list[Pair]:
    """Pairs of `data_dir/PAIRS.tsv` (all splits when `split` is None), in file order.

    With `for_training=True` only the train split may be asked for.
    """
    if for_training and split != TRAIN_SPLIT:
        raise SplitError(f"training code may only read split {TRAIN_SPLIT!r}, asked for {split!r}")
    folder = Path(data_dir) if data_dir is not None else DEFAULT_DATA_DIR
    index = folder / INDEX_NAME
    if not index.is_file():
        raise FileNotFoundError(f"no {INDEX_NAME} in {folder}")
    with index.open(newline="") as f:
        reader = csv.DictReader(f, delimiter="\t")
        missing = set(COLUMNS) - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f"{index} lacks columns {sorted(missing)}")
        pairs = [_parse_row(row, folder) for row in reader]
    selected = [p for p in pairs if split is None or p.split == split]
    if for_training:
        check_training_pairs(selected)
    return selected


def check_training_pairs(pairs: list[Pair]) -> None:
    """Raise `SplitError` unless every pair is from the train split."""
    bad = [p.pair_id for p in pairs if p.split != TRAIN_SPLIT]
    if bad:
        raise SplitError(f"non-train pairs in a training context: {bad[:5]}")


def training_pairs(data_dir: Path | None = None) -> list[Pair]:
    """The only way training code obtains pairs: the train split, checked."""
    pairs = load_pairs(data_dir, TRAIN_SPLIT, for_training=True)
    if not pairs:
        raise ValueError(f"no train pairs in {data_dir or DEFAULT_DATA_DIR}")
    return pairs


def _imread_unchanged(path: Path) -> NDArray[np.generic]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return np.asarray(image)


def _imread(path: Path) -> NDArray[np.uint8]:
    image = _imread_unchanged(path)
    if image.dtype != np.uint8:
        raise ValueError(f"{path}: expected 8-bit pixels, got {image.dtype}")
    return image.astype(np.uint8, copy=False)


def load_gray_u8(path: Path) -> NDArray[np.uint8]:
    """(H, W) uint8 grayscale; colour images via OpenCV's BGR2GRAY (alpha ignored)."""
    image = _imread(path)
    if image.ndim == 3 and image.shape[2] == 4:
        image = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2BGR), dtype=np.uint8)
    if image.ndim == 3:
        image = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
    return np.ascontiguousarray(image)


def load_gray(path: Path) -> NDArray[np.float32]:
    """(H, W) float32 grayscale in [0, 1]."""
    return load_gray_u8(path).astype(np.float32) / np.float32(255.0)


def load_gt(pair: Pair) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Left-image disparity in pixels and its validity mask, as `eval::gt` loads it in Rust.

    In every `gt_format` the disparity is stored value / gt_scale. A pixel is unknown where the
    stored value is gt_invalid (required for the integer formats, optional for pfm) and, in a
    PFM, where it is not finite; a PFM's unknown pixels get disparity 0, so no `inf` goes on.
    """
    if pair.gt is None:
        raise ValueError(f"pair {pair.pair_id} has no ground truth")
    scale = np.float32(pair.gt_scale)
    if pair.gt_format == "pfm":
        try:
            stored = read_pfm(pair.gt)
        except ValueError as e:  # a colour PFM, a truncated one: one line naming the pair
            raise ValueError(f"pair {pair.pair_id}: {e}") from None
        valid = np.isfinite(stored)
        if pair.gt_invalid is not None:
            valid &= stored != np.float32(pair.gt_invalid)
        return np.where(valid, stored / scale, np.float32(0)).astype(np.float32), valid
    dtype = GT_DTYPES.get(pair.gt_format)
    if dtype is None:
        known = ", ".join(GT_FORMATS)
        raise ValueError(
            f"pair {pair.pair_id}: unknown gt_format {pair.gt_format!r} (known: {known})"
        )
    if pair.gt_invalid is None:
        raise ValueError(f"pair {pair.pair_id}: gt_format {pair.gt_format} needs a gt_invalid")
    image = _imread_unchanged(pair.gt)
    if image.ndim != 2 or image.dtype != dtype:
        depth = "a 16-bit" if dtype == np.uint16 else "an 8-bit"
        raise ValueError(
            f"{pair.gt}: expected {depth} single-channel disparity map "
            f"(gt_format {pair.gt_format}), got {image.dtype} with shape {image.shape}"
        )
    valid = image != pair.gt_invalid
    disparity = image.astype(np.float32) / scale
    return disparity, valid
