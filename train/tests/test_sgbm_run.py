"""bino_train.sgbm_run: the SGBM job runner `bino eval` calls."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.sgbm_run import main


def test_recovers_a_known_shift(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    texture = (rng.random((48, 200)) * 255).astype(np.uint8)
    texture = cv2.GaussianBlur(texture, (3, 3), 0)
    shift = 7
    left = texture[:, 20:180]
    right = texture[:, 20 + shift : 180 + shift]  # left(x) = right(x - d) with d = shift
    cv2.imwrite(str(tmp_path / "l.pgm"), left)
    cv2.imwrite(str(tmp_path / "r.pgm"), right)
    jobs = tmp_path / "jobs.tsv"
    jobs.write_text(f"{tmp_path / 'l.pgm'}\t{tmp_path / 'r.pgm'}\t{tmp_path / 'd.npy'}\n")
    main(["--list", str(jobs)])
    disparity = np.load(tmp_path / "d.npy")
    assert disparity.shape == (48, 160) and disparity.dtype == np.float32
    valid = disparity >= 0
    assert valid.mean() > 0.5
    assert np.median(np.abs(disparity[valid] - shift)) < 0.5


def test_unreadable_image_is_an_error(tmp_path: Path) -> None:
    jobs = tmp_path / "jobs.tsv"
    jobs.write_text(
        f"{tmp_path / 'missing.pgm'}\t{tmp_path / 'missing.pgm'}\t{tmp_path / 'd.npy'}\n"
    )
    with pytest.raises(SystemExit, match="cannot read"):
        main(["--list", str(jobs)])
