"""The census residual study's parts on tiny synthetic pairs: the zero-initialised net (and its
int8 twin) returns the census readout exactly, the costs are sampled at the anchor's
disparities, the head's evidence lands on its channels, the training items carry the labeled
train pairs' ground truth (never the holdout), crops keep features and labels aligned, the int8
twin follows the float net, and training lowers the error on what it trains on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from test_labeled import HELD, SHIFT, W, write_labeled

from bino_train.census_companion import box_sums, pixel_hamming, refine_search, refined
from bino_train.census_residual import TrainConfig, predict, train_net
from bino_train.census_residual_data import (
    WIDTH_SCALES,
    crop_batch,
    real_items,
    synthetic_items,
    train_pairs,
)
from bino_train.census_residual_maps import (
    HEAD_DELTA_PX,
    MAX_HAMMING,
    OFFSETS,
    census_maps,
    channel_names,
)
from bino_train.census_residual_net import QuantisedNet, ResidualNet
from bino_train.census_selector_cells import census_cells
from bino_train.head_eval import fill_rejected
from bino_train.profile import to_u8
from bino_train.refine import CELL, RefineParams, upsample_float
from bino_train.synthetic import shifted_pair

DISP = 6
N = 16


def _pair(seed: int = 1, h: int = 32, w: int = 64) -> tuple[np.ndarray, np.ndarray]:
    left, right = shifted_pair(seed, h, w, DISP)
    return to_u8(left), to_u8(right)


def test_the_zero_initialised_net_and_its_int8_twin_return_the_census_readout() -> None:
    left, right = _pair()
    h, w = left.shape
    cc = census_cells(pixel_hamming(left, right, N, False), h // CELL, w // CELL)
    grid = fill_rejected(cc.disparity, cc.kept)
    boxed = box_sums(pixel_hamming(left, right, N + 8, True), RefineParams().box_radius)
    census_ref = refined(boxed, grid, cc.kept, refine_search(w))
    for anchor, expected in (("ref", census_ref), ("up", upsample_float(grid, h, w))):
        maps = census_maps(left, right, N, anchor)
        assert np.array_equal(maps.refined, census_ref)
        assert np.array_equal(maps.anchor, expected.astype(np.float32))
        channels = range(maps.features.shape[0])
        net = ResidualNet(len(channels)).eval()
        assert np.array_equal(predict(net, maps, channels), maps.anchor)
        twin = QuantisedNet(net, [torch.from_numpy(maps.features)[None]])
        assert np.array_equal(predict(twin, maps, channels), maps.anchor)
    # The census finds the shift: the anchor is the true disparity away from the left border.
    assert np.median(np.abs(census_ref[:, 2 * DISP :] - DISP)) < 0.5


def test_costs_are_sampled_at_the_anchors_disparities() -> None:
    left, right = _pair(seed=2)
    maps = census_maps(left, right, N, "ref")
    names = channel_names("ref")
    assert len(names) == maps.features.shape[0]
    raw = pixel_hamming(left, right, N + 8, True)
    centre = np.floor(maps.anchor.astype(np.float64) + 0.5).astype(np.int64)
    ys, xs = np.mgrid[0 : left.shape[0], 0 : left.shape[1]]
    for k in OFFSETS:
        sampled = raw[ys, xs, np.clip(centre + k, 0, N + 7)] / MAX_HAMMING
        assert np.allclose(maps.features[names.index(f"ham{k:+d}")], sampled, atol=1e-6)
    runner = maps.census.runner_up[ys // CELL, xs // CELL] * CELL
    expected = np.clip((runner - maps.anchor) / HEAD_DELTA_PX, -4, 4)
    assert np.allclose(maps.features[names.index("(runner-anchor)/8")], expected, atol=1e-5)
    # Where the anchor is right, its own disparity costs least: box sums and aggregate.
    inside = (np.abs(maps.anchor - DISP) < 0.25) & (xs >= 2 * DISP)
    assert inside.mean() > 0.5
    for kind in ("box", "agg"):
        stack = np.stack([maps.features[names.index(f"{kind}{k:+d}")] for k in OFFSETS])
        assert (stack.argmin(axis=0)[inside] == OFFSETS.index(0)).mean() > 0.9
    # The right view warped by a correct anchor is the left view.
    diff = maps.features[names.index("|left-warped|")]
    assert diff[inside].mean() < 0.02


def test_the_heads_evidence_lands_on_its_channels() -> None:
    left, right = _pair(seed=3)
    h, w = left.shape
    candidates = N // CELL
    logits = np.full((candidates, h // CELL, w // CELL), -20.0)
    logits[3] = 20.0  # the head sure of candidate 3 (12 px) everywhere
    maps = census_maps(left, right, N, "ref", logits)
    names = channel_names("ref", candidates)
    assert len(names) == maps.features.shape[0]
    assert np.allclose(maps.features[names.index("head_p3")], 1.0, atol=1e-6)
    probs = maps.features[[names.index(f"head_p{i}") for i in range(candidates)]]
    assert np.allclose(probs.sum(axis=0), 1.0, atol=1e-5)
    delta = maps.features[names.index("(head-anchor)/8")]
    assert np.allclose(delta, np.clip((12.0 - maps.anchor) / HEAD_DELTA_PX, -4, 4), atol=1e-4)


def test_training_items_are_the_labeled_train_pairs_at_the_studys_widths(tmp_path: Path) -> None:
    data = write_labeled(tmp_path)
    pairs = train_pairs(data)
    assert [p.pair_id for p in pairs] == ["lab0", "lab1"]  # not HELD, not the eval pair
    assert HELD not in [p.pair_id for p in pairs]
    items = real_items(pairs, 160, 32, "ref", 2, np.random.default_rng(0))
    assert len(items) == 2 * len(WIDTH_SCALES) * 2
    for it in items:
        width = it.gt.shape[1]
        assert it.features.shape[1:] == it.gt.shape == it.valid.shape
        truth = SHIFT * width / W
        assert np.allclose(it.gt[it.valid], truth)
        assert not it.valid[:2].any()  # the stored map's unknown rows stay unknown
    assert sorted({it.gt.shape[1] for it in items}) == [128, 160, 200]


def test_crops_keep_features_and_labels_aligned() -> None:
    items = synthetic_items(3, 24, "ref", np.random.default_rng(4))
    x, anchor, gt, valid = crop_batch(items, 5, (16, 32), np.random.default_rng(5), 0.5)
    assert x.shape == (5, len(channel_names("ref")), 16, 32)
    assert anchor.shape == gt.shape == valid.shape == (5, 16, 32)
    # channel 0 is the anchor over the census range: the crop's own anchor.
    assert torch.allclose(x[:, 0] * 24, anchor, atol=0.05)
    assert bool(valid.all())


def test_the_int8_twin_follows_the_float_net() -> None:
    torch.manual_seed(0)
    net = ResidualNet(6).eval()
    torch.nn.init.normal_(net.out.weight, std=0.05)
    x = torch.rand(2, 6, 24, 40)
    twin = QuantisedNet(net, [x])
    with torch.no_grad():
        exact = net(x)
    err = (twin(x) - exact).abs()
    assert float(err.max()) < 0.1 * float(exact.abs().max()) + 1.0 / 16


def test_training_lowers_the_error_on_its_crops() -> None:
    items = synthetic_items(4, 24, "ref", np.random.default_rng(6))
    channels = list(range(len(channel_names("ref"))))
    cfg = TrainConfig(steps=250, batch=2, crop=(24, 48), lr=3e-3)
    _, info = train_net(items, channels, cfg)
    last = info["curve"][-1]
    assert last["l1"] < last["anchor_l1"]
