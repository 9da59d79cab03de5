"""Labeled train pairs (issue 40): dense real ground truth for the heads, the held-out folder,
bad input, and the layered synthetic scenes."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.augment import AugmentConfig
from bino_train.head_data import DataConfig, HeadSampler, head_training_pairs, validation_pairs
from bino_train.labeled import (
    LABELED_HOLDOUT,
    LabeledSource,
    heldout_labeled_pairs,
    labeled_pairs,
    load_checked_gt,
    resize_labels,
)
from bino_train.labeled_folder import write_folder
from bino_train.pairs import COLUMNS, load_gt, load_pairs
from bino_train.pfm import encode_pfm, read_pfm
from bino_train.synth_train import layered_sample, layered_scene

W, H, SHIFT = 320, 96, 12
HELD = LABELED_HOLDOUT[1]
PLAIN = replace(AugmentConfig(), photometric_prob=0.0, noise_prob=0.0, flip_prob=0.0)
"""No nuisances, so crops can be compared with the stored views."""


def write_labeled(folder: Path, gt_maps: dict[str, bytes] | None = None) -> Path:
    """Train pairs lab0, lab1 and HELD (right = left shifted by SHIFT px, GT = SHIFT, unknown
    in the first rows), one unlabeled train pair and one eval pair. `gt_maps` replaces a
    pair's PFM bytes."""
    rng = np.random.default_rng(0)
    rows = ["\t".join(COLUMNS)]
    for pair_id, split, labeled in [
        ("lab0", "train", True),
        ("lab1", "train", True),
        (HELD, "train", True),
        ("plain", "train", False),
        ("ev", "eval", True),
    ]:
        wide = rng.integers(0, 256, size=(H, W + SHIFT), dtype=np.uint8)
        wide = cv2.GaussianBlur(wide, (3, 3), 0)
        left, right = wide[:, SHIFT:], wide[:, :W]  # left(x) = wide(x + S) = right(x + S - S)
        for name, image in ((f"{pair_id}_l.png", left), (f"{pair_id}_r.png", right)):
            assert cv2.imwrite(str(folder / name), np.ascontiguousarray(image))
        gt, fmt, scale = "", "", ""
        if labeled:
            disparity = np.full((H, W), float(SHIFT), np.float32)
            disparity[:4] = np.inf
            gt, fmt, scale = f"{pair_id}.pfm", "pfm", "1"
            data = (gt_maps or {}).get(pair_id, encode_pfm(disparity))
            (folder / gt).write_bytes(data)
        fields = [pair_id, split, "middeval3_q", f"{pair_id}_l.png", f"{pair_id}_r.png"]
        rows.append("\t".join([*fields, gt, fmt, scale, "", str(W), str(H)]))
    (folder / "PAIRS.tsv").write_text("\n".join(rows) + "\n")
    return folder


def test_labeled_pairs_are_train_pairs_with_ground_truth_and_the_holdout_is_not_trained(
    tmp_path: Path,
) -> None:
    data = write_labeled(tmp_path)
    assert [p.pair_id for p in labeled_pairs(data)] == ["lab0", "lab1", HELD]
    assert [p.pair_id for p in heldout_labeled_pairs(data)] == [HELD]
    assert HELD in {p.pair_id for p in validation_pairs(data)}
    trained = {p.pair_id for p in head_training_pairs(data)}
    assert HELD not in trained and "ev" not in trained and "lab0" in trained


def test_ground_truth_of_another_size_is_a_one_line_error_naming_the_pair(tmp_path: Path) -> None:
    small = encode_pfm(np.full((H // 2, W // 2), 3.0, np.float32))
    data = write_labeled(tmp_path, {"lab1": small})
    pair = next(p for p in load_pairs(data) if p.pair_id == "lab1")
    with pytest.raises(ValueError) as err:
        load_checked_gt(pair, (H, W))
    message = str(err.value)
    assert "\n" not in message
    assert "pair lab1" in message and "160x48" in message and "320x96" in message
    # A source over the train pairs refuses it before any crop is cut.
    cfg = replace(DataConfig(), augment=PLAIN)
    with pytest.raises(ValueError, match="pair lab1: ground truth"):
        LabeledSource(labeled_pairs(data), cfg)


def test_colour_pfm_is_a_one_line_error_naming_the_pair(tmp_path: Path) -> None:
    colour = b"PF\n320 96\n-1.0\n" + np.zeros(3 * W * H, "<f4").tobytes()
    data = write_labeled(tmp_path, {"lab0": colour})
    pair = next(p for p in load_pairs(data) if p.pair_id == "lab0")
    with pytest.raises(ValueError) as err:
        load_gt(pair)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("pair lab0: ") and "colour PFM" in message


def test_resized_labels_scale_disparity_by_the_width_factor() -> None:
    disparity = np.tile(np.arange(8, dtype=np.float32) * 2.0, (4, 1))
    valid = np.ones_like(disparity, dtype=bool)
    valid[0, 0] = False
    half, ok = resize_labels(disparity, valid, 4)
    assert half.shape == (2, 4)
    # Pixel centres: column j of 4 samples source column floor((j + 0.5) * 2) = 2j + 1.
    np.testing.assert_array_equal(half[0], [1.0, 3.0, 5.0, 7.0])
    assert ok.all()  # (0, 0) is not a sampled centre


def test_labeled_crops_carry_the_ground_truth_in_patch_columns_at_their_width(
    tmp_path: Path,
) -> None:
    data = write_labeled(tmp_path)
    cfg = replace(DataConfig(), augment=PLAIN, max_disp=16)
    source = LabeledSource([p for p in labeled_pairs(data) if p.pair_id != HELD], cfg)
    seen = set()
    for seed in range(12):
        sample = source.sample(np.random.default_rng(seed))
        assert sample.left.shape == (48, 160) and not sample.synthetic
        labels = sample.label[np.isfinite(sample.label)]
        assert labels.size > 0
        # The width is a multiple of 16 in [160, 320]: the label is SHIFT * width / W / 4.
        width = float(labels[0]) * 4 * W / SHIFT
        assert 160 - 1e-3 <= width <= 320 + 1e-3
        assert abs(width / 16 - round(width / 16)) < 1e-3
        np.testing.assert_allclose(labels, labels[0], rtol=1e-6)
        seen.add(round(width))
    assert len(seen) > 1, "crops at several widths"


def test_sampler_mixes_labeled_synthetic_and_pseudo_labels(tmp_path: Path) -> None:
    data = write_labeled(tmp_path)
    cfg = replace(
        DataConfig(),
        augment=PLAIN,
        max_disp=16,
        synthetic_fraction=0.4,
        labeled_fraction=0.4,
        synthetic_kind="layered",
    )
    sampler = HeadSampler(cfg, 0, data)
    assert sampler.labeled is not None and sampler.real is not None
    assert {p.pair_id for p in sampler.labeled.store.pairs} == {"lab0", "lab1"}
    samples = sampler.samples(range(40))
    synthetic = sum(s.synthetic for s in samples)
    assert 5 < synthetic < 30
    with pytest.raises(ValueError, match="labeled_fraction"):
        HeadSampler(replace(cfg, labeled_fraction=0.7), 0, data)


def test_layered_scenes_are_exact_and_cover_the_candidate_range() -> None:
    rng = np.random.default_rng(3)
    top = 0.0
    for _ in range(30):
        left, right, disparity = layered_scene(rng, 48, 160, 60.0)
        assert 0.0 <= disparity.min() and disparity.max() <= 60.0
        top = max(top, float(disparity.max()))
        xs = (np.arange(160)[None, :] - disparity).astype(np.float32)
        ys = np.broadcast_to(np.arange(48, dtype=np.float32)[:, None], xs.shape)
        warped = cv2.remap(right, xs, np.ascontiguousarray(ys), cv2.INTER_LINEAR)
        inside = xs >= 1
        # Visible pixels match exactly; occluded ones (a nearer surface in the right view) don't.
        assert np.median(np.abs(warped - left)[inside]) < 1e-4
    assert top > 50.0
    cfg = replace(DataConfig(), max_disp=16)
    sample = layered_sample(np.random.default_rng(0), cfg)
    labels = sample.label[np.isfinite(sample.label)]
    assert sample.synthetic and labels.size > 0 and labels.max() <= 15.0


def test_heldout_folder_has_profile_sized_ground_truth(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    data = write_labeled(tmp_path / "data")
    out = tmp_path / "out"
    assert write_folder(out, 160, data) == [HELD]
    (pair,) = load_pairs(out, "val")
    disparity, valid = load_gt(pair)
    left = cv2.imread(str(pair.left), cv2.IMREAD_UNCHANGED)
    assert left.shape == disparity.shape == (48, 160) and (pair.width, pair.height) == (160, 48)
    np.testing.assert_allclose(disparity[valid], SHIFT / 2)
    assert not valid[:2].any() and valid[2:].all()
    assert np.isnan(read_pfm(pair.gt)[0]).all()  # type: ignore[arg-type]


def test_init_head_takes_a_twelve_candidate_heads_weights_and_refuses_another_kind(
    tmp_path: Path,
) -> None:
    import torch

    from bino_train.head import HeadConfig, make_head
    from bino_train.head_train import initial_head

    small = HeadConfig(desc_dim=16, proj_dim=16, groups=4, hidden=8, middle_layers=1, max_disp=12)
    torch.manual_seed(1)
    trained = make_head(small)
    path = tmp_path / "last.pt"
    torch.save({"head_config": small.to_dict(), "head": trained.state_dict()}, path)
    head = initial_head(path, replace(small, max_disp=16))
    assert head.cfg.max_disp == 16
    for name, tensor in trained.state_dict().items():
        assert torch.equal(head.state_dict()[name], tensor), name
    with pytest.raises(ValueError, match="another kind"):
        initial_head(path, replace(small, hidden=16, max_disp=16))


def test_head_curves_read_the_labeled_validation_records(tmp_path: Path) -> None:
    import json

    from bino_train.head_curves import HEAD_COLOURS, smoothed, step_series, val_series
    from bino_train.head_curves import main as curves_main

    records = [{"kind": "start", "step": 0}]
    records += [{"step": s, "loss": 10.0 / s} for s in range(10, 410, 10)]
    records += [
        {
            "kind": "val",
            "step": 200 * k,
            "val_gt_w160": {"head_lr": {"epe": 1.0 / k, "bad1tok": 5.0}},
            "val_gt_w320": {"head_lr": {"epe": 2.0 / k, "bad1tok": 9.0}},
            "val_synthetic": {"epe": 0.5},
            "val_sgbm_lr": None,
        }
        for k in (1, 2)
    ]
    assert len(step_series(records, "loss")) == 40
    assert smoothed(step_series(records, "loss"))[0][0] == 200.0
    assert val_series(records, "val_gt_w320", "head_lr", "epe") == [(200.0, 2.0), (400.0, 1.0)]
    assert val_series(records, "val_sgbm_lr", "epe") == []
    run = tmp_path / "run"
    run.mkdir()
    (run / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    curves_main(["--run", str(run), "--out", str(tmp_path / "c.png")])
    image = cv2.imread(str(tmp_path / "c.png"))
    assert image is not None and image.shape[0] > 100
    for colour in (HEAD_COLOURS["w160"], HEAD_COLOURS["w320"], HEAD_COLOURS["synthetic"]):
        assert np.all(image == np.array(colour, np.uint8), axis=-1).any(), colour
