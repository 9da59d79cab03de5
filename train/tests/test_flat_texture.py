"""The flat-region measure: the texture both views share against what each has alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bino_train.flat_texture import main, measure
from bino_train.synth_folder import FLAT_GRAIN_LEVELS, write_folder
from bino_train.synthetic import fine_grain

H, W, D = 96, 160, 7.0


def _flat_pair(grain: float, noise: float, seed: int = 0) -> tuple[np.ndarray, ...]:
    """A flat grey surface at disparity D with `grain` grey levels of shared micro-texture,
    `noise` grey levels of independent noise per view."""
    rng = np.random.default_rng(seed)
    surface = 120.0 + grain * fine_grain(rng, H, W + 16)
    left = surface[:, 8 : 8 + W]
    right = surface[:, 8 + int(D) : 8 + int(D) + W]  # right(x - D) == left(x)
    left = left + rng.normal(0.0, noise, (H, W))
    right = right + rng.normal(0.0, noise, (H, W))
    return left.astype(np.float32), right.astype(np.float32), np.full((H, W), D, np.float32)


@pytest.mark.parametrize(("grain", "noise"), [(1.5, 2.0), (0.2, 1.0), (3.0, 0.5)])
def test_shared_texture_and_independent_noise_come_apart(grain: float, noise: float) -> None:
    r = measure(*_flat_pair(grain, noise))
    assert r is not None and r.flat_share > 0.5
    assert r.shared == pytest.approx(grain, rel=0.15, abs=0.15)
    # White noise keeps most of itself through the high-pass (a 1.5 px blur takes a little).
    assert 0.8 * noise < r.alone < 1.05 * noise


def test_unknown_disparity_and_busy_texture_are_not_measured() -> None:
    left, right, disparity = _flat_pair(1.5, 2.0)
    assert measure(left, right, np.full_like(disparity, np.nan)) is None
    rng = np.random.default_rng(3)
    busy = rng.uniform(0, 255, (H, W)).astype(np.float32)
    assert measure(busy, busy, disparity) is None


def test_command_measures_real_and_synthetic_folders(tmp_path: Path) -> None:
    write_folder(tmp_path / "synth", 160, 96, 3)
    # The same scenes as labeled train pairs stand in for ../shared/data's.
    write_folder(tmp_path / "data", 160, 96, 3)
    index = tmp_path / "data" / "PAIRS.tsv"
    index.write_text(index.read_text().replace("\tval\t", "\ttrain\t"))
    out = tmp_path / "flat.json"
    args = ["--width", "160", "--data", str(tmp_path / "data"), "--folder", str(tmp_path / "synth")]
    main([*args, "--json", str(out)])
    report = json.loads(out.read_text())
    real, synth = report["labeled train pairs at 160 px"], report[str(tmp_path / "synth")]
    assert real == synth and real["pairs"] >= 1
    assert real["shared"] == pytest.approx(FLAT_GRAIN_LEVELS, rel=0.3)
    with pytest.raises(SystemExit, match="no PAIRS.tsv in .*nothing"):
        main(["--data", str(tmp_path / "nothing")])
