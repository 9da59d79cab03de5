"""The census re-ranking study's pure parts on tiny synthetic pairs: the head's evidence, the
neighbour agreement, the features, the pipelines (the winner everywhere is census+lr+ref exactly,
the re-check revives and drops cells), the labels' weights, the 3-way choice, and a whole study
end to end."""

from __future__ import annotations

import numpy as np

from bino_train.census_companion import box_sums, pixel_hamming, refined
from bino_train.census_rerank import (
    MODELS,
    PIPELINES,
    Pipeline,
    RerankCells,
    assemble,
    census_features,
    combine,
    constant,
    head_mass,
    neighbour_agreement,
    predict,
    rerank_cells,
    rule_lrswap,
    study,
    training_cells,
)
from bino_train.census_selector import (
    PairCells,
    Selector,
    base_readouts,
    cell_ground_truth,
    cell_spread,
    census_cells,
    census_selector,
)
from bino_train.refine import CELL

ROWS, COLS, DISP = 4, 12, 4


def _cells(seed: int = 3) -> RerankCells:
    """A textured pair shifted by 8 px (2 columns) with noise, and a random head."""
    rng = np.random.default_rng(seed)
    h, w = CELL * ROWS, CELL * COLS
    scene = rng.integers(0, 256, size=(h, w + 8)).astype(np.int64)
    left = np.clip(scene[:, 8:] + rng.integers(-6, 7, size=(h, w)), 0, 255).astype(np.uint8)
    right = np.clip(scene[:, :w] + rng.integers(-6, 7, size=(h, w)), 0, 255).astype(np.uint8)
    gt = np.full((h, w), 8.0, dtype=np.float32)
    valid = rng.uniform(size=(h, w)) > 0.1
    hamming = pixel_hamming(left, right, CELL * DISP, False)
    census = census_cells(hamming, ROWS, COLS)
    base = PairCells(
        pair_id=f"synthetic{seed}",
        census=census,
        census_nouniq=census.disparity,
        head=rng.uniform(0, 3, (ROWS, COLS)),
        head_kept=rng.uniform(size=(ROWS, COLS)) > 0.3,
        head_peak=rng.uniform(0.1, 1, (ROWS, COLS)),
        head_entropy=rng.uniform(0, 1, (ROWS, COLS)),
        gt_cell=cell_ground_truth(gt, valid),
        gradient=rng.uniform(0, 30, (ROWS, COLS)),
        periodicity=rng.uniform(0, 1, (ROWS, COLS)),
        spread=cell_spread(gt, valid),
        gt=gt,
        valid=valid,
        boxed=box_sums(pixel_hamming(left, right, CELL * DISP + 8, True), 4),
        search=2,
    )
    return rerank_cells(base, hamming, rng.normal(0, 2, (DISP, ROWS, COLS)))


def test_head_mass_sums_the_window_around_the_rounded_candidate() -> None:
    prob = np.array([[[0.1, 0.2, 0.3, 0.4], [0.7, 0.1, 0.1, 0.1]]])
    d = np.array([[2.2, 0.4]])
    assert np.allclose(head_mass(prob, d), [[0.9, 0.8]])
    assert np.allclose(head_mass(prob, d, window=0), [[0.3, 0.7]])


def test_neighbour_agreement_reads_kept_neighbours_inside_the_grid() -> None:
    ref = np.array([[1.0, 2.0, 5.0], [1.0, 1.0, 1.0]])
    kept = np.array([[True, True, False], [True, True, True]])
    left, right, up = neighbour_agreement(np.full((2, 3), 1.5), ref, kept)
    assert left.tolist() == [[False, True, True], [False, True, True]]
    assert right.tolist() == [[True, False, False], [True, True, False]]
    assert up.tolist() == [[False, False, False], [True, True, False]]


def test_features_are_in_unit_range_and_the_head_adds_columns() -> None:
    r = _cells()
    names, f = census_features(r, 1, False)
    head_names, g = census_features(r, 2, True)
    assert f.shape == (ROWS, COLS, len(names)) and g.shape == (ROWS, COLS, len(head_names))
    assert len(head_names) == len(names) + 3
    assert f.min() >= 0 and f.max() <= 1 and g.min() >= 0 and g.max() <= 1
    # The winner's left-right column is the census's own check.
    assert np.array_equal(f[..., names.index("winner_lr")], r.base.census.lr.astype(float))


def test_the_winner_everywhere_is_census_lr_ref_exactly() -> None:
    r = _cells()
    b = r.base
    census = base_readouts(b)["census"]
    for pipe in (Pipeline(), Pipeline(recheck=True)):
        grid, kept = assemble(r, pipe, constant(r, 0))
        assert np.array_equal(grid, census[0]) and np.array_equal(kept, census[1])
        assert np.array_equal(predict(r, pipe, constant(r, 0)), refined(b.boxed, *census, b.search))
    # Without the uniqueness test the kept mask is the left-right check alone.
    assert np.array_equal(assemble(r, Pipeline(uniq=False), constant(r, 0))[1], b.census.lr)


def test_the_recheck_revives_and_drops_switched_cells() -> None:
    r = _cells()
    everywhere = constant(r, 1)
    kept_plain = assemble(r, Pipeline(), everywhere)[1]
    kept_checked = assemble(r, Pipeline(recheck=True), everywhere)[1]
    assert np.array_equal(kept_plain, r.base.census.kept)
    assert np.array_equal(kept_checked, r.runner_lr)
    swap = rule_lrswap(r)
    assert ((swap == 1) == (~r.base.census.lr & r.runner_lr)).all()


def test_labels_weigh_nothing_where_no_choice_is_kept() -> None:
    r = _cells()
    pipe = Pipeline()
    _, f = census_features(r, 1, False)
    x, label, weight = training_cells(
        r, pipe, 1, f, predict(r, pipe, constant(r, 0)), predict(r, pipe, constant(r, 1))
    )
    assert x.shape == (ROWS * COLS, f.shape[-1]) and label.shape == weight.shape
    assert (weight[~r.base.census.kept.reshape(-1)] == 0).all()


def test_combine_takes_the_highest_positive_logit_and_q8_agrees() -> None:
    x = np.array([[[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]])
    runner = Selector(np.array([2.0, 0.0]), -1.0)
    head = Selector(np.array([0.0, 3.0]), -1.0)
    for q8 in (False, True):
        assert combine([runner, head], [x, x], [1, 2], q8).tolist() == [[1, 2, 0]]
        assert combine([runner], [x], [1], q8).tolist() == [[1, 0, 0]]
    keep = census_selector(2)
    assert not combine([keep, keep], [x, x], [1, 2], False).any()


def test_a_small_study_runs_end_to_end() -> None:
    pairs = [_cells(s) for s in (1, 2, 3)]
    out = study(pairs, (PIPELINES[0], PIPELINES[4]), MODELS[:1], settings=[(1e-2, 0.0)])
    r = out["readouts"]
    base = r["census+lr+ref"]
    assert base["epe_over_census"] == 1.0 and not base["meets_target"]
    assert base["switched_pct"] == 0 and base["changed_pct"] == 0
    assert not r["rr2-census/lr+ref"]["needs_encoder"]
    assert r["oracle3/lr,recheck+ref"]["needs_encoder"]
    # The oracle never does worse than the census on these pairs' cells to first order.
    assert r["oracle2/lr,recheck+ref"]["mean"]["epe"] <= base["mean"]["epe"] + 1e-6
    assert set(r["rr2-census/lr+ref"]["pairs"]) == {p.base.pair_id for p in pairs}
