"""Head recipes of issue 13: label confidence, the photometric term, the descriptor cache and
the validation split that is never the eval split."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import HEADER, TINY_DATA, cpu_trainer, save_tiny_cache, tiny_cached_config

from bino_train.export import random_encoder
from bino_train.head import HeadConfig, HeadOutput, head_loss
from bino_train.head_cache import load_cache, load_cache_meta, save_cache
from bino_train.head_data import (
    DataConfig,
    cell_weights,
    consistent_sgbm,
    head_training_pairs,
    lr_disagreement,
    sgbm_disparity,
    validation_pairs,
)
from bino_train.head_train import SMOKE_ENCODER, SMOKE_HEAD, HeadTrainer
from bino_train.head_val import ValidationSet
from bino_train.pairs import load_pairs
from bino_train.photometric import photometric_terms, pixel_disparity, warp_right
from bino_train.probe import upsample_disparity
from bino_train.synthetic import shifted_pair

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _write_index(folder: Path, datasets: dict[str, int]) -> Path:
    """An index only (validation_pairs reads no pixels); one eval row as well."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = ["\t".join(HEADER)]
    for dataset, n in datasets.items():
        for i in range(n):
            rows.append(f"{dataset}_{i:03d}\ttrain\t{dataset}\tl.png\tr.png\t\t\t\t\t160\t96")
    rows.append("ev\teval\tmb\tl.png\tr.png\tgt.png\tpng_u8\t4\t0\t160\t96")
    (folder / "PAIRS.tsv").write_text("\n".join(rows) + "\n")
    return folder


def test_validation_holds_out_the_last_eighth_of_each_dataset(tmp_path: Path) -> None:
    data = _write_index(tmp_path, {"video": 17, "small": 3, "mid": 8})
    held = [p.pair_id for p in validation_pairs(data)]
    assert held == ["mid_007", "video_014", "video_015", "video_016"]
    train = {p.pair_id for p in head_training_pairs(data)}
    assert not train & set(held)
    assert len(train) + len(held) == 28
    assert all(p.split == "train" for p in validation_pairs(data))
    assert "ev" not in train | set(held)
    assert len(load_pairs(data)) == 29


def test_sgbm_left_right_disagreement_is_small_on_a_true_shift() -> None:
    left, right = shifted_pair(3, 96, 200, 8)
    u8 = [np.clip(np.rint(v * 255), 0, 255).astype(np.uint8) for v in (left, right)]
    disp, valid = sgbm_disparity(u8[0], u8[1])
    diff = lr_disagreement(u8[0], u8[1], disp)
    interior = valid.copy()
    interior[:, :40] = False
    assert np.median(diff[interior]) <= 0.25
    consistent_disp, kept, confidence = consistent_sgbm(u8[0], u8[1])
    assert np.array_equal(consistent_disp, disp)
    assert kept.sum() <= valid.sum() and (kept <= valid).all()
    assert ((confidence > 0) == kept).all() or (confidence[~kept] == 1.0).all()
    assert abs(float(np.median(disp[kept])) - 8.0) <= 0.25
    # A wrong right view: the checks throw most of it away.
    _, scrambled_kept, _ = consistent_sgbm(u8[0], np.ascontiguousarray(u8[1][::-1]))
    assert scrambled_kept.sum() < 0.5 * kept.sum()


def test_cell_weights_are_confidence_times_valid_share() -> None:
    confidence = np.full((4, 8), 0.5, dtype=np.float32)
    valid = np.ones((4, 8), dtype=bool)
    valid[:, 4:6] = False  # second cell: half its pixels
    label = np.array([[1.0, 2.0]], dtype=np.float32)
    assert cell_weights(confidence, valid, label).tolist() == [[0.5, 0.25]]
    label[0, 1] = np.nan
    assert cell_weights(confidence, valid, label).tolist() == [[0.5, 0.0]]


def _output(disparity: torch.Tensor, d: int = 4) -> HeadOutput:
    logits = torch.zeros(1, d, *disparity.shape[1:])
    return HeadOutput(logits, disparity, torch.ones_like(disparity))


def test_head_loss_is_a_weighted_mean_over_cells() -> None:
    pred = torch.tensor([[[0.0, 0.0]]])
    target = torch.tensor([[[0.5, 1.0]]])  # smooth L1 (beta 1): 0.125 and 0.5
    even = head_loss(_output(pred), target, ce_weight=0.0)
    assert even.smooth_l1 == pytest.approx((0.125 + 0.5) / 2)
    weighted = head_loss(_output(pred), target, 0.0, torch.tensor([[[3.0, 1.0]]]))
    assert weighted.smooth_l1 == pytest.approx((3 * 0.125 + 0.5) / 4)
    dropped = head_loss(_output(pred), target, 0.0, torch.tensor([[[1.0, 0.0]]]))
    assert dropped.smooth_l1 == pytest.approx(0.125) and dropped.cells == 1


def test_pixel_disparity_is_the_eval_upsampling() -> None:
    cols = torch.rand(1, 3, 7) * 5
    ours = pixel_disparity(cols)[0].numpy()
    assert np.allclose(ours, upsample_disparity(cols[0].numpy()), atol=1e-5)


def test_warp_with_the_true_disparity_reconstructs_the_left_view() -> None:
    left, right = shifted_pair(1, 32, 96, 6)
    images = torch.from_numpy(np.stack([left, right]))[None]
    exact = warp_right(images[:, 1], torch.full((1, 32, 96), 6.0))
    assert torch.allclose(exact[0][0, :, 6:], images[0, 0, :, 6:], atol=1e-5)
    assert not exact[1][0, :, :6].any() and exact[1][0, :, 6:].all()
    right_cols = photometric_terms(torch.full((1, 8, 24), 1.5), images).reconstruction
    wrong_cols = photometric_terms(torch.full((1, 8, 24), 0.5), images).reconstruction
    assert float(right_cols) < 0.02 < float(wrong_cols)


def test_photometric_gradient_points_to_the_true_disparity() -> None:
    left, right = shifted_pair(2, 32, 96, 6)
    images = torch.from_numpy(np.stack([left, right]))[None]
    cols = torch.full((1, 8, 24), 1.0, requires_grad=True)  # 4 px, the truth is 6 px
    photometric_terms(cols, images).reconstruction.backward()
    assert cols.grad is not None and float(cols.grad[:, :, 4:].mean()) < 0


def _cache_trainer(cache_path: Path, data: DataConfig, data_dir: Path) -> HeadTrainer:
    cfg = replace(tiny_cached_config(cache_path, data), photometric=0.5, smoothness=0.05)
    return cpu_trainer(cfg, random_encoder(0, SMOKE_ENCODER), data_dir)


def test_cached_training_matches_its_data_and_resumes_exactly(
    data_dir: Path, tmp_path: Path
) -> None:
    data = replace(TINY_DATA, synthetic_fraction=0.5, label_weighting="lr")
    path = tmp_path / "cache.pt"
    cache = save_tiny_cache(path, random_encoder(0, SMOKE_ENCODER), data, 0, 12, data_dir)
    loaded = load_cache(path)
    assert loaded.count == 12 and load_cache_meta(path)["count"] == 12
    assert loaded.data.images is not None and loaded.data.images.shape == (12, 2, 32, 96)
    assert loaded.data.weight is not None
    labelled = torch.isfinite(loaded.data.label)
    assert (loaded.data.weight[~labelled] == 0).all()
    assert (loaded.data.weight[labelled] <= 1).all() and (loaded.data.weight[labelled] > 0).any()
    # Synthetic crops carry exact labels: weight 1 wherever labelled.
    syn = loaded.data.synthetic
    assert (loaded.data.weight[syn][labelled[syn]] == 1).all()

    straight = _cache_trainer(path, data, data_dir)
    records = [straight.train_step() for _ in range(6)]
    assert all("photometric" in r for r in records)
    split = _cache_trainer(path, data, data_dir)
    for _ in range(3):
        split.train_step()
    resumed = _cache_trainer(path, data, data_dir)
    resumed.load_state_dict(split.state_dict())
    for _ in range(3):
        resumed.train_step()
    for name, tensor in straight.head.state_dict().items():
        assert torch.equal(tensor, resumed.head.state_dict()[name]), name

    with pytest.raises(ValueError, match="other data"):
        _cache_trainer(path, replace(data, synthetic_fraction=1.0), data_dir)
    other = tmp_path / "other.pt"
    save_cache(replace(cache, meta={**cache.meta, "encoder_sha256": "0" * 64}), other)
    with pytest.raises(ValueError, match="another encoder"):
        _cache_trainer(other, data, data_dir)


def test_validation_scores_synthetic_crops_without_the_eval_split(data_dir: Path) -> None:
    encoder = random_encoder(0, SMOKE_ENCODER)
    val = ValidationSet.build(encoder, data_dir, TINY_DATA, synthetic_count=4)
    assert val.pairs == []  # the fixture's datasets are too small to hold one out
    from bino_train.head import StereoHead

    head = StereoHead(HeadConfig(**{**SMOKE_HEAD.to_dict(), "desc_dim": SMOKE_ENCODER.dim}))
    result = val.score(head)
    assert result["val_sgbm"] is None and result["val_pairs"] == 0
    assert 0 < result["val_synthetic"]["epe"] < 50


def test_head_cache_rejects_a_candidate_count_outside_its_range(tmp_path: Path) -> None:
    from bino_train.head_cache import main

    with pytest.raises(SystemExit, match="--max-disp 1 is outside 2..64"):
        main(
            [
                "--encoder",
                str(tmp_path / "e.pt"),
                "--out",
                str(tmp_path / "c.pt"),
                "--max-disp",
                "1",
            ]
        )
