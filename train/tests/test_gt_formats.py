"""Ground truth as datasets ship it: PFM (Middlebury 2014, ETH3D) and 16-bit PNG (KITTI)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.pairs import Pair, load_gt, load_pairs
from bino_train.pfm import decode_pfm, read_pfm

HEADER = "pair_id split dataset left right gt gt_format gt_scale gt_invalid width height".split()

# Asymmetric in both axes, so a missed row flip or a transpose shows; inf and NaN are unknown.
MAP = np.array([[1.0, 2.0, np.inf], [0.0, np.nan, 12.0]], dtype=np.float32)


def pfm_bytes(image: np.ndarray, little_endian: bool) -> bytes:
    """A grayscale PFM of `image` (top row first): rows stored bottom-up."""
    dtype = "<f4" if little_endian else ">f4"
    h, w = image.shape
    header = f"Pf\n{w} {h}\n{'-1.0' if little_endian else '1.0'}\n".encode()
    return header + image[::-1].astype(dtype).tobytes()


def gt_pair(path: Path, gt_format: str, scale: float, invalid: int | None) -> Pair:
    return Pair(
        pair_id="p",
        split="eval",
        dataset="synthetic",
        left=path,
        right=path,
        gt=path,
        gt_format=gt_format,
        gt_scale=scale,
        gt_invalid=invalid,
        width=0,
        height=0,
    )


@pytest.mark.parametrize("little_endian", [True, False])
def test_pfm_of_either_byte_order_reads_top_row_first_as_opencv_does(
    tmp_path: Path, little_endian: bool
) -> None:
    path = tmp_path / "disp.pfm"
    path.write_bytes(pfm_bytes(MAP, little_endian))
    stored = read_pfm(path)
    assert stored.dtype == np.float32 and stored.flags.c_contiguous
    np.testing.assert_array_equal(stored, MAP)
    # An independent reader agrees on orientation and byte order.
    np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), MAP)


@pytest.mark.parametrize("little_endian", [True, False])
def test_pfm_ground_truth_divides_by_gt_scale_and_masks_non_finite(
    tmp_path: Path, little_endian: bool
) -> None:
    path = tmp_path / "disp.pfm"
    path.write_bytes(pfm_bytes(MAP, little_endian))
    disparity, valid = load_gt(gt_pair(path, "pfm", 2.0, None))
    np.testing.assert_array_equal(valid, [[True, True, False], [True, False, True]])
    np.testing.assert_array_equal(disparity, [[0.5, 1.0, 0.0], [0.0, 0.0, 6.0]])
    # A stated gt_invalid masks that value too.
    _, valid = load_gt(gt_pair(path, "pfm", 2.0, 0))
    np.testing.assert_array_equal(valid, [[True, True, False], [False, False, True]])


def test_png_u16_is_value_over_scale_with_zero_unknown(tmp_path: Path) -> None:
    path = tmp_path / "disp.png"
    # KITTI's encoding: disparity * 256, 0 where unknown.
    stored = np.array([[0, 256], [2560 + 128, 65535]], dtype=np.uint16)
    assert cv2.imwrite(str(path), stored)
    disparity, valid = load_gt(gt_pair(path, "png_u16", 256.0, 0))
    np.testing.assert_array_equal(valid, [[False, True], [True, True]])
    np.testing.assert_array_equal(disparity, np.float32([[0.0, 1.0], [10.5, 65535 / 256]]))
    # The bit depth must match the format, either way round.
    with pytest.raises(ValueError, match="expected an 8-bit"):
        load_gt(gt_pair(path, "png_u8", 1.0, 0))
    small = tmp_path / "u8.png"
    assert cv2.imwrite(str(small), stored.astype(np.uint8))
    with pytest.raises(ValueError, match="expected a 16-bit"):
        load_gt(gt_pair(small, "png_u16", 256.0, 0))


def test_index_rows_of_every_format(tmp_path: Path) -> None:
    rows = [
        ["a", "eval", "mb2014", "l.png", "r.png", "a.pfm", "pfm", "1", "", "3", "2"],
        ["b", "eval", "kitti", "l.png", "r.png", "b.png", "png_u16", "256", "0", "2", "2"],
    ]
    lines = ["\t".join(HEADER)] + ["\t".join(r) for r in rows]
    (tmp_path / "PAIRS.tsv").write_text("\n".join(lines) + "\n")
    (tmp_path / "a.pfm").write_bytes(pfm_bytes(MAP, True))
    a, b = load_pairs(tmp_path, "eval")
    assert (a.gt_format, a.gt_scale, a.gt_invalid) == ("pfm", 1.0, None)
    assert (b.gt_format, b.gt_scale, b.gt_invalid) == ("png_u16", 256.0, 0)
    np.testing.assert_array_equal(load_gt(a)[1], np.isfinite(MAP))
    with pytest.raises(ValueError, match="unknown gt_format 'exr'"):
        load_gt(replace(a, gt_format="exr"))
    with pytest.raises(ValueError, match="png_u8 needs a gt_invalid"):
        load_gt(replace(a, gt_format="png_u8"))


def test_malformed_pfm_is_refused_with_the_problem(tmp_path: Path) -> None:
    good = pfm_bytes(np.ones((2, 2), dtype=np.float32), True)
    cases = [
        (b"P5\n2 2\n255\n", "not a PFM file"),
        (b"PF\n1 1\n-1\n" + bytes(12), "colour PFM"),
        (b"Pf\n", "no width"),
        (b"Pf\n2", "no height"),
        (b"Pf\n2 x\n-1\n", "bad height 'x'"),
        (b"Pf\n-2 2\n-1\n", "bad width '-2'"),
        (b"Pf\n99999999999 1\n-1\n", "bad width"),
        (b"Pf\n0 2\n-1\n", r"empty image \(0x2\)"),
        (b"Pf\n100000 100000\n-1\n" + bytes(4), "declares 100000x100000 pixels"),
        (b"Pf\n2 2\n0\n", "gives no byte order"),
        (b"Pf\n2 2\n-1", "no line end after the scale"),
        (good[:-3], "truncated: 13 bytes of pixels, 2x2 needs 16"),
        (good + b"\0", "1 bytes after the 2x2 pixels"),
    ]
    for data, needle in cases:
        with pytest.raises(ValueError, match=needle):
            decode_pfm(data)
    path = tmp_path / "cut.pfm"
    path.write_bytes(good[:-3])
    with pytest.raises(ValueError, match="cut.pfm"):
        read_pfm(path)
