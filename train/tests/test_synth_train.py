"""The training scenes' textureless surfaces: the shipped heads' faint grain or a real one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bino_train.head_data import DataConfig
from bino_train.synth_train import flat_texture, layered_sample
from bino_train.synthetic import high_pass


def _grain_levels(surface: np.ndarray) -> float:
    return float(np.sqrt(np.mean(high_pass(surface * 255.0)[8:-8, 8:-8] ** 2)))


def test_flat_surfaces_carry_the_grain_asked_for() -> None:
    faint = flat_texture(np.random.default_rng(0), 64, 96)
    real = flat_texture(np.random.default_rng(0), 64, 96, grain_levels=1.5)
    assert _grain_levels(faint) < 0.2
    assert _grain_levels(real) == pytest.approx(1.5, rel=0.2)


def test_the_config_grain_reaches_the_sampled_scenes() -> None:
    cfg = replace(DataConfig(), synthetic_kind="layered", max_disp=16)
    grainy = replace(cfg, flat_grain_levels=1.5)
    differs = 0
    for seed in range(8):
        c = layered_sample(np.random.default_rng([seed, 1]), cfg)
        d = layered_sample(np.random.default_rng([seed, 1]), grainy)
        differs += not np.array_equal(c.left, d.left)
    # Scenes without a flat surface are the same; most have one.
    assert 0 < differs
