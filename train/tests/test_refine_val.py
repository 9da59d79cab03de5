"""Choosing the refinement's parameters on held-out train pairs (bino_train.refine_val)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bino_train import refine_val
from bino_train.export import random_encoder
from bino_train.head import StereoHead
from bino_train.pairs import training_pairs
from bino_train.refine import RefineParams


def test_q8_rounds_half_up_and_saturates() -> None:
    tokens = np.array([[0.0, 0.5 / 256, 1.0, 300.0, -1.0]], dtype=np.float32)
    assert refine_val.to_q8(tokens).tolist() == [[0, 1, 256, 65535, 0]]


def test_validation_scores_each_parameter_set_against_the_unrefined_grid(
    data_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The tiny data set has no dataset of four pairs, so hold out its train pairs directly.
    monkeypatch.setattr(refine_val, "validation_pairs", lambda d: training_pairs(d))
    torch.manual_seed(0)
    params = [RefineParams(search=0), RefineParams(search=3)]
    out = refine_val.validate(random_encoder(0), StereoHead(), 160, params, data_dir)
    assert out["width"] == 160 and out["pairs"] == len(training_pairs(data_dir))
    base = out["unrefined"]["epe"]
    assert [r["search"] for r in out["refined"]] == [0, 3]
    for row in out["refined"]:
        assert np.isfinite(row["epe"]) and 0.0 <= row["bad2"] <= 100.0
        assert row["epe_change"] == pytest.approx(row["epe"] / base - 1.0)


def test_nuisances_degrade_the_right_view_and_equalised_rows_follow(
    data_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(refine_val, "validation_pairs", lambda d: training_pairs(d))
    torch.manual_seed(0)
    params = [RefineParams()]
    clean = refine_val.validate(random_encoder(0), StereoHead(), 160, params, data_dir)
    blurred = refine_val.validate(
        random_encoder(0), StereoHead(), 160, params, data_dir, "blur", equalised=True
    )
    assert blurred["nuisance"] == "blur"
    assert [r["equalised"] for r in blurred["refined"]] == [False, True]
    assert blurred["refined"][0]["epe"] != clean["refined"][0]["epe"]
    assert blurred["refined"][1]["epe"] != blurred["refined"][0]["epe"]


def test_degrade_is_seeded_and_refuses_unknown_nuisances() -> None:
    view = np.tile(np.arange(0, 250, 10, dtype=np.uint8), (8, 1))
    assert np.array_equal(refine_val.degrade(view, "none", 0), view)
    assert np.array_equal(
        refine_val.degrade(view, "noise", 3), refine_val.degrade(view, "noise", 3)
    )
    assert not np.array_equal(refine_val.degrade(view, "noise", 3), view)
    assert np.abs(np.diff(refine_val.degrade(view, "blur", 0).astype(int), axis=1)).max() <= 10
    with pytest.raises(ValueError, match="unknown nuisance"):
        refine_val.degrade(view, "fog", 0)


def test_gain_gamma_and_occlusion_follow_bino_evals_definitions() -> None:
    view = np.array([[0, 100, 250, 64]], dtype=np.uint8)
    # 0.7 v + 20 rounded (bino_host::nuisance's own test: 20, 90, 195, 65).
    assert refine_val.degrade(view, "gain", 0).tolist() == [[20, 90, 195, 65]]
    gamma = refine_val.degrade(view, "gamma", 0)
    assert gamma[0, 0] == 0 and gamma[0, 1] == round(255 * (100 / 255) ** 0.6)
    big = np.full((60, 100), 7, dtype=np.uint8)
    occluded = refine_val.degrade(big, "occlude", 1)
    share = float((occluded == 128).mean())
    assert 0.2 <= share < 0.24
    assert np.array_equal(occluded, refine_val.degrade(big, "occlude", 1))
