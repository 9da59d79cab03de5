"""Controlled benchmark: construction, determinism, oracle scores."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from bino_train.benchmark import (
    make_benchmark,
    match_offsets,
    offset_metrics,
    run_all,
    run_benchmark,
    shifted_views,
)
from bino_train.probe import window_descriptors


def test_shifted_views_follow_the_disparity_convention() -> None:
    crop = np.random.default_rng(0).random((48, 160), dtype=np.float32)
    left, right = shifted_views(crop, 12)
    assert np.array_equal(left[:, 12:], right[:, :-12])  # left(x) = right(x - 12)
    assert np.array_equal(right[:, -1], crop[:, -13])  # reflect padding past the edge


def test_match_offsets_of_shifted_descriptors() -> None:
    dl = torch.randn(3, 20, 8)
    dr = torch.randn(3, 20, 8)
    dr[:, :17] = dl[:, 3:]  # right column p - 3 holds left column p
    offsets = match_offsets(dl, dr)
    assert (offsets[:, 3:] == 3).all()
    assert offset_metrics(offsets[:, 3:] - 3) == {
        "pck0": 100.0,
        "pck1": 100.0,
        "pck2": 100.0,
        "epe_tok": 0.0,
    }
    assert offset_metrics(torch.tensor([0, 1, 2, -3]))["pck1"] == 50.0


def test_oracle_descriptor_scores_pck0_of_one_on_easy(data_dir: Path) -> None:
    sets = make_benchmark(data_dir, pairs=6, seed=0)
    shifts = [p.shift_cols for p in sets["easy"]]
    assert all(0 <= k <= 9 for k in shifts) and len(set(shifts)) > 1
    # On noise images a 4x4 cell is unique, so its own pixels are a perfect descriptor.
    easy = run_benchmark(lambda images: window_descriptors(images, 4), sets["easy"])
    assert easy["pck0"] == 100.0 and easy["epe_tok"] == 0.0
    hard = run_benchmark(lambda images: window_descriptors(images, 4), sets["hard"])
    assert hard["pck0"] < 100.0


def test_benchmark_is_deterministic_given_a_seed(data_dir: Path) -> None:
    a = make_benchmark(data_dir, pairs=4, seed=3)
    b = make_benchmark(data_dir, pairs=4, seed=3)
    c = make_benchmark(data_dir, pairs=4, seed=4)
    for name in ("easy", "hard"):
        for pa, pb in zip(a[name], b[name], strict=True):
            assert np.array_equal(pa.left, pb.left) and np.array_equal(pa.right, pb.right)
            assert pa.shift_cols == pb.shift_cols
    assert not np.array_equal(a["easy"][0].left, c["easy"][0].left)
    describe = lambda images: window_descriptors(images, 12)  # noqa: E731
    assert run_all(describe, a) == run_all(describe, b)
