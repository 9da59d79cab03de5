"""The census selector study's pure parts on tiny synthetic grids: the uniqueness margin, the
head's statistics, the features, the fit, the Q8 choice, and that a selector started at the census
reproduces the census map exactly."""

from __future__ import annotations

import numpy as np

from bino_train.census_companion import box_sums, pixel_hamming, refined
from bino_train.census_selector import (
    FEATURES,
    CensusCells,
    PairCells,
    Selector,
    base_readouts,
    cell_ground_truth,
    cell_spread,
    census_selector,
    choose_q8,
    epe_gain,
    features,
    fill_background,
    fit_fold,
    fit_selector,
    head_stats,
    oracle_choice,
    select,
    uniqueness,
)


def _pair(seed: int = 3, rows: int = 4, cols: int = 8) -> PairCells:
    rng = np.random.default_rng(seed)
    h, w = 4 * rows, 4 * cols
    left = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    right = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    gt = rng.uniform(0, 8, size=(h, w)).astype(np.float32)
    valid = rng.uniform(size=(h, w)) > 0.1
    census = CensusCells(
        disparity=rng.uniform(0, 3, (rows, cols)),
        lr=rng.uniform(size=(rows, cols)) > 0.2,
        unique=rng.uniform(size=(rows, cols)) > 0.2,
        margin=rng.uniform(0, 1, (rows, cols)),
        runner_up=rng.uniform(0, 3, (rows, cols)),
    )
    return PairCells(
        pair_id=f"synthetic{seed}",
        census=census,
        census_nouniq=census.disparity,
        head=rng.uniform(0, 3, (rows, cols)),
        head_kept=rng.uniform(size=(rows, cols)) > 0.3,
        head_peak=rng.uniform(0.1, 1, (rows, cols)),
        head_entropy=rng.uniform(0, 1, (rows, cols)),
        gt_cell=cell_ground_truth(gt, valid),
        gradient=rng.uniform(0, 10, (rows, cols)),
        periodicity=rng.uniform(0, 1, (rows, cols)),
        spread=cell_spread(gt, valid),
        gt=gt,
        valid=valid,
        boxed=box_sums(pixel_hamming(left, right, 20, True), 4),
        search=2,
    )


def test_uniqueness_rejects_a_flat_aggregate_and_measures_the_margin() -> None:
    costs = np.array([[[10.0, 10.0, 10.0, 10.0, 10.0], [4.0, 5.0, 9.0, 8.0, 20.0]]])
    unique, margin = uniqueness(costs, 10)
    assert unique.tolist() == [[False, True]]
    # Winner 4 at 0; the best candidate more than one away is 8 (at 3): (8 - 4) / 8.
    assert np.allclose(margin, [[0.0, 0.5]])
    assert uniqueness(costs, 0)[0].all()


def test_head_statistics_of_flat_and_peaked_logits() -> None:
    logits = np.zeros((4, 1, 2))
    logits[2, 0, 1] = 50.0
    peak, entropy = head_stats(logits)
    assert np.allclose(peak, [[0.25, 1.0]])
    assert np.allclose(entropy, [[1.0, 0.0]], atol=1e-9)


def test_features_are_in_unit_range_and_read_the_checks() -> None:
    c = _pair()
    f = features(c)
    assert f.shape == (*c.head.shape, len(FEATURES))
    assert f.min() >= 0.0 and f.max() <= 1.0
    kept = c.census.lr & c.census.unique
    assert np.array_equal(f[..., FEATURES.index("census_kept")], kept.astype(float))
    head_only = c.head_kept & ~kept
    assert np.array_equal(f[..., FEATURES.index("head_only_kept")], head_only.astype(float))


def test_a_selector_started_at_the_census_reproduces_the_census_map_exactly() -> None:
    c = _pair()
    bases = base_readouts(c)
    sel = census_selector()
    f = features(c)
    assert not sel.choose(f).any() and not choose_q8(sel, f).any()
    grid, kept = select([bases["census"], bases["head"]], sel.choose(f).astype(np.int64))
    assert np.array_equal(grid, bases["census"][0]) and np.array_equal(kept, bases["census"][1])
    assert np.array_equal(
        refined(c.boxed, grid, kept, c.search), refined(c.boxed, *bases["census"], c.search)
    )


def test_the_fit_learns_a_rule_and_q8_agrees_with_float() -> None:
    rng = np.random.default_rng(5)
    x = rng.uniform(size=(4000, 3))
    label = x[:, 0] - x[:, 1] > 0.2
    weight = rng.uniform(0.5, 1.5, 4000)
    sel = fit_selector(x, label, weight, prior=census_selector(3), l2=1e-4)
    assert sel.weights[0] > 1 and sel.weights[1] < -1
    assert (sel.choose(x) == label).mean() > 0.95
    clear = np.abs(sel.logits(x)) > 0.5
    assert np.array_equal(choose_q8(sel, x)[clear], sel.choose(x)[clear])
    # No weight: the prior comes back.
    prior = census_selector(3)
    assert fit_selector(x, label, np.zeros(4000), prior=prior) is prior


def test_a_fold_where_the_other_cell_never_helps_keeps_the_census() -> None:
    rng = np.random.default_rng(6)
    train = [
        (rng.uniform(size=(200, 3)), np.zeros(200, dtype=bool), rng.uniform(size=200))
        for _ in range(3)
    ]
    sel, info = fit_fold(train, [(1e-3, 0.0)])
    assert info["setting"] == "census"
    assert isinstance(sel, Selector) and not sel.choose(train[0][0]).any()
    assert epe_gain(np.ones(200, dtype=bool), train[0]) < 0


def test_the_oracle_takes_the_closer_cell_and_the_census_where_unknown() -> None:
    kept = np.ones((1, 3), dtype=bool)
    census = (np.array([[1.0, 2.0, 3.0]]), kept)
    head = (np.array([[1.5, 0.0, 0.0]]), kept)
    gt = np.array([[1.4, 2.0, np.nan]])
    assert oracle_choice([census, head], gt).tolist() == [[1, 0, 0]]


def test_background_fill_takes_the_lower_neighbour() -> None:
    d = np.array([[5.0, 0.0, 0.0, 2.0, 0.0], [0.0, 3.0, 0.0, 0.0, 0.0]])
    kept = np.array([[True, False, False, True, False], [False, True, False, False, False]])
    assert fill_background(d, kept).tolist() == [[5, 2, 2, 2, 2], [3, 3, 3, 3, 3]]


def test_periodicity_finds_stripes_and_not_noise_or_ramps() -> None:
    from bino_train.census_selector import REPETITIVE_RISE
    from bino_train.census_selector_cells import cell_periodicity
    from bino_train.synthetic import smooth_texture

    xs = np.arange(160)[None, :].repeat(48, 0)
    inner = (slice(1, -1), slice(4, -4))  # away from the padded borders
    for period in (4, 6, 12, 16):
        stripes = (128 + 80 * np.sin(2 * np.pi * xs / period)).astype(np.uint8)
        assert cell_periodicity(stripes).shape == (12, 40)
        assert cell_periodicity(stripes)[inner].min() > REPETITIVE_RISE
    for seed in range(3):
        noise = np.random.default_rng(seed).integers(0, 256, (48, 160)).astype(np.uint8)
        smooth = (255 * smooth_texture(np.random.default_rng(seed), 48, 160)).astype(np.uint8)
        assert (cell_periodicity(noise)[inner] > REPETITIVE_RISE).mean() < 0.01
        assert (cell_periodicity(smooth)[inner] > REPETITIVE_RISE).mean() < 0.01
    ramp = (xs * 1.5).astype(np.uint8)
    assert cell_periodicity(ramp)[inner].max() < 0.1
