"""The shared stereo head: size, correlation, labels, pseudo-label split guard, training,
ONNX export and exact resume."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from conftest import TINY_DATA

import bino_train.augment as augment
from bino_train.export import random_encoder
from bino_train.head import (
    PAPER_HEAD_PARAMETERS,
    HeadConfig,
    StereoHead,
    export_head_onnx,
    head_candidates,
    head_output_names,
    supervised_cells,
    with_candidates,
)
from bino_train.head_data import (
    DataConfig,
    HeadSampler,
    PseudoLabelSource,
    Scene,
    cell_labels,
    render_scene,
    sgbm_disparity,
    synthetic_sample,
)
from bino_train.head_eval import (
    consistent,
    evaluate_head,
    fill_rejected,
    head_lr,
    mirror_descriptors,
)
from bino_train.head_train import (
    SMOKE_ENCODER,
    SMOKE_HEAD,
    EncoderSource,
    HeadTrainConfig,
    HeadTrainer,
    cosine_lr,
    main,
)
from bino_train.model import parameter_count
from bino_train.pairs import SplitError, load_gray_u8, load_pairs
from bino_train.probe import similarity_volume, window_descriptors, wta_subtoken
from bino_train.synthetic import shifted_pair, smooth_texture

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_parameter_count_is_the_papers() -> None:
    n = parameter_count(StereoHead())
    assert abs(n - PAPER_HEAD_PARAMETERS) <= 0.05 * PAPER_HEAD_PARAMETERS, n


@pytest.mark.parametrize("shift", [0, 1, 3, 7, 11])
def test_correlation_of_shifted_descriptors_peaks_at_the_shift(shift: int) -> None:
    torch.manual_seed(0)
    head = StereoHead()
    t, p = 6, 30
    right = torch.randn(1, t, p, 128)
    left = torch.randn(1, t, p, 128)
    left[:, :, shift:] = right[:, :, : p - shift]  # left(p) = right(p - shift)
    with torch.no_grad():
        corr = head.correlation(head.project(left), head.project(right)).sum(dim=1)[0]
        mask = head.candidate_mask(left)[0]
    assert corr.shape == (12, t, p)
    best = corr.argmax(dim=0)
    assert torch.all(best[:, shift:] == shift)
    cols = torch.arange(p).view(1, 1, -1)
    ks = torch.arange(12).view(-1, 1, 1)
    assert torch.equal(mask, (cols >= ks).float().expand(12, t, p))
    assert torch.all(corr[mask == 0] == 0)  # candidates outside the right view carry nothing


def test_head_candidates_follow_the_sgbm_range_of_the_width() -> None:
    # The Rust rule (readout_eval::head_candidates): 12 at w160, 16 at w320, capped at 64.
    assert [head_candidates(w) for w in (32, 160, 320, 400, 4000)] == [12, 12, 16, 20, 64]


def test_more_candidates_keep_the_weights_and_the_near_logits() -> None:
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=16)).eval()
    wider = with_candidates(head, SMOKE_HEAD.max_disp + 4)
    assert wider.cfg.max_disp == SMOKE_HEAD.max_disp + 4
    left, right = torch.randn(1, 3, 20, 16), torch.randn(1, 3, 20, 16)
    with torch.no_grad():
        near, far = head(left, right), wider(left, right)
    assert far.logits.shape[1] == near.logits.shape[1] + 4
    # Candidate 0 lies further from the disparity edge than the convolutions reach.
    reach = 2 + SMOKE_HEAD.middle_layers
    if SMOKE_HEAD.max_disp > reach:
        assert torch.allclose(near.logits[:, 0], far.logits[:, 0], atol=1e-4)


def test_masked_candidates_get_no_probability() -> None:
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=16))
    with torch.no_grad():
        out = head(torch.randn(2, 3, 9, 16), torch.randn(2, 3, 9, 16))
    prob = torch.softmax(out.logits, dim=1)
    for p in range(9):
        assert float(prob[:, p + 1 :, :, p].sum()) < 1e-6
        assert torch.all(out.disparity[..., p] <= p + 1e-5)
    assert torch.all((out.confidence > 0) & (out.confidence <= 1))


def test_synthetic_scene_follows_left_equals_right_shifted() -> None:
    rng = np.random.default_rng(0)
    h, w, margin = 24, 64, 50
    bg, fg = smooth_texture(rng, h, w + margin), smooth_texture(rng, h, w + margin)
    scene = Scene(a=6.0, rect=(4, 20, 30, 50), fg=17.0)
    left, right, disparity = render_scene(scene, bg, fg, h, w, margin)
    assert np.all(disparity >= 0)
    # Integer disparities and no jitter: left(x) == right(x - d) exactly, wherever both views
    # show the same surface (background columns not hidden by the rectangle in the right view).
    for y, x in [(2, 10), (10, 40), (15, 49), (22, 63), (10, 8), (4, 30)]:
        d = int(disparity[y, x])
        assert left[y, x] == pytest.approx(right[y, x - d], abs=1e-6), (y, x)
    labels = cell_labels(disparity, np.ones_like(disparity, dtype=bool))
    assert labels[0, 0] == pytest.approx(6.0 / 4)  # px -> patch columns
    assert labels[2, 9] == pytest.approx(17.0 / 4)
    assert np.isnan(labels[1, 7])  # cell with pixels of both surfaces: no single disparity


def test_synthetic_labels_agree_with_matching() -> None:
    # End to end: cosine WTA on pixel-window descriptors finds the labelled disparity.
    cfg = DataConfig(augment=replace(DataConfig().augment, photometric_prob=0, noise_prob=0))
    errors = []
    for i in range(6):
        s = synthetic_sample(np.random.default_rng([3, i]), cfg)
        dl, dr = window_descriptors([s.left, s.right], 12)
        wta = wta_subtoken(similarity_volume(dl, dr, cfg.max_disp)).numpy()
        ok = np.isfinite(s.label)
        assert 0 <= np.nanmin(s.label) and np.nanmax(s.label) <= cfg.max_disp - 1
        errors.append(np.abs(wta[ok] - s.label[ok]))
    assert np.median(np.concatenate(errors)) < 0.5
    assert (np.concatenate(errors) < 1.0).mean() > 0.75


def test_cell_labels_average_valid_pixels_and_reject_edges() -> None:
    disp = np.zeros((4, 12), np.float32)
    disp[:, :4] = 8.0
    disp[:, 4:8] = np.array([4.0, 5.0, 6.0, 7.0])
    disp[:, 8:10], disp[:, 10:] = 4.0, 20.0
    valid = np.ones_like(disp, dtype=bool)
    valid[0, :2] = False
    labels = cell_labels(disp, valid, min_valid=12, max_spread=4.0)
    assert labels[0, 0] == pytest.approx(2.0)  # 14 valid pixels at 8 px
    assert labels[0, 1] == pytest.approx(5.5 / 4)
    assert np.isnan(labels[0, 2])  # spread 16 px
    valid[:, :4] = False
    assert np.isnan(cell_labels(disp, valid)[0, 0])


def test_supervised_cells_need_a_reachable_candidate() -> None:
    target = torch.tensor([[[0.0, 1.4, 2.6, float("nan"), 12.0, 3.0]]])
    assert supervised_cells(target, 12).tolist() == [[[True, True, False, False, False, True]]]


def test_sgbm_labels_use_the_same_sign_convention() -> None:
    left, right = shifted_pair(seed=1, height=64, width=160, disparity=9)
    to_u8 = [np.rint(v * 255).astype(np.uint8) for v in (left, right)]
    disp, valid = sgbm_disparity(to_u8[0], to_u8[1])
    assert valid[:, 40:].mean() > 0.9
    assert np.median(disp[valid]) == pytest.approx(9.0, abs=0.25)


def test_pseudo_labels_never_read_the_eval_split(
    data_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    read: list[Path] = []

    def spy(path: Path) -> Any:
        read.append(Path(path))
        return load_gray_u8(path)

    monkeypatch.setattr(augment, "load_gray_u8", spy)
    sampler = HeadSampler(replace(TINY_DATA, synthetic_fraction=0.0), seed=0, data_dir=data_dir)
    samples = sampler.samples(range(24))
    assert not any(s.synthetic for s in samples)
    assert read, "the pseudo-label source read no images"
    train = {p for pair in load_pairs(data_dir, "train") for p in (pair.left, pair.right)}
    evals = {p for pair in load_pairs(data_dir, "eval") for p in (pair.left, pair.right, pair.gt)}
    assert set(read) <= train and not set(read) & evals
    with pytest.raises(SplitError):
        PseudoLabelSource(load_pairs(data_dir, "eval"), TINY_DATA)


def test_smoke_run_reduces_the_loss(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--random-init-seed", "0", "--out", str(tmp_path / "smoke"), "--smoke"])
    assert exit_info.value.code == 0


@pytest.mark.parametrize("rows,cols", [(12, 40), (7, 9), (3, 25)])
def test_onnx_export_matches_torch(tmp_path: Path, rows: int, cols: int) -> None:
    torch.manual_seed(1)
    head = StereoHead().eval()
    path = tmp_path / "head.onnx"
    export_head_onnx(head, path, provenance="test", logits=True)
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    allowed = {"LayerNormalization", "MatMul", "Add", "Sub", "Mul", "Concat", "Slice"}
    allowed |= {"Unsqueeze", "Squeeze", "Transpose", "Conv", "Relu", "Softmax", "ReduceSum"}
    allowed |= {"ReduceMax", "Constant", "Identity"}
    assert ops <= allowed, ops - allowed
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == head_output_names(True)
    rng = np.random.default_rng(0)
    dl = rng.normal(size=(1, rows, cols, 128)).astype(np.float32)
    dr = rng.normal(size=(1, rows, cols, 128)).astype(np.float32)
    got = session.run(None, {"desc_left": dl, "desc_right": dr})
    with torch.no_grad():
        out = head(torch.from_numpy(dl), torch.from_numpy(dr))
    assert got[0].shape == (1, rows, cols)
    assert np.abs(got[0] - out.disparity.numpy()).max() < 1e-4
    assert np.abs(got[1] - out.confidence.numpy()).max() < 1e-5
    assert np.abs(got[2] - out.logits.numpy()).max() < 1e-3


def _tiny_trainer(data_dir: Path) -> HeadTrainer:
    cfg = HeadTrainConfig(
        head=replace(SMOKE_HEAD, desc_dim=SMOKE_ENCODER.dim),
        data=replace(TINY_DATA, synthetic_fraction=0.5),
        batch=4,
        pool=8,
        refresh=2,
        warmup=0.2,
        schedule_steps=10,
    )
    source = EncoderSource("random-init", seed=0, config=SMOKE_ENCODER.to_dict())
    encoder = random_encoder(0, SMOKE_ENCODER)
    return HeadTrainer(cfg, encoder, source, data_dir, torch.device("cpu"))


def _assert_same(a: Any, b: Any, where: str = "") -> None:
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


def test_resume_is_exact(data_dir: Path, tmp_path: Path) -> None:
    straight = _tiny_trainer(data_dir)
    for _ in range(6):  # past one full turn of the 4-group pool
        straight.train_step()
    split = _tiny_trainer(data_dir)
    for _ in range(3):
        split.train_step()
    halfway = split.state_dict()
    torch.save(halfway, tmp_path / "half.pt")
    resumed = _tiny_trainer(data_dir)
    resumed.load_state_dict(torch.load(tmp_path / "half.pt", weights_only=False))
    for _ in range(3):
        resumed.train_step()
    a, b = straight.state_dict(), resumed.state_dict()
    for key in ("head", "optimizer", "step", "train_config", "head_config", "encoder_source"):
        _assert_same(a[key], b[key], key)
    assert not torch.equal(a["head"]["stem.weight"], halfway["head"]["stem.weight"])


def test_cli_resume_continues_the_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with pytest.raises(SystemExit):
        main(["--random-init-seed", "0", "--out", str(out), "--smoke", "--steps", "4"])
    first = torch.load(out / "last.pt", weights_only=False)
    assert first["step"] == 4 and first["encoder_source"]["kind"] == "random-init"
    main(["--out", str(out), "--resume", "--steps", "6", "--no-eval", "--log-every", "1"])
    state = torch.load(out / "last.pt", weights_only=False)
    assert state["step"] == 6
    records = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if r.get("kind") == "start"] == [0, 4]
    assert [r["step"] for r in records if "loss" in r][-2:] == [5, 6]
    with pytest.raises(SystemExit):  # a fresh run never overwrites a checkpoint
        main(["--random-init-seed", "0", "--out", str(out), "--steps", "1"])


def test_evaluation_scores_head_probe_and_sgbm(data_dir: Path) -> None:
    encoder = random_encoder(0, SMOKE_ENCODER)
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=SMOKE_ENCODER.dim))
    result = evaluate_head(encoder, head, data_dir, per_pair=True)
    assert result["pairs"] == 2 and set(result["per_pair"]) == {"e0", "e1"}
    for name in ("head", "head+lr", "probe", "sgbm"):
        assert {"epe", "bad1tok", "bad2", "density"} <= set(result[name])
        assert np.isfinite(result[name]["epe"])
    assert result["head"]["density"] == 100.0
    assert set(result["per_pair"]["e0"]) == {"head", "head+lr"}


def test_left_right_check_and_fill_follow_the_core_rules() -> None:
    # The examples of bino_core::lr's tests: cells 2..4 read 2 columns and land on right cells
    # 0..2, which agree; cells 0 and 1 land on right cell 0, which reads 2.
    left = np.array([[0.0, 1.0, 2.0, 2.0, 2.0]])
    right = np.array([[2.0, 2.0, 2.0, 0.0, 0.0]])
    assert consistent(left, right, 0.5).tolist() == [[False, False, True, True, True]]
    assert consistent(left, right, 1.0)[0].sum() == 4
    assert not consistent(np.array([[3.0]]), np.array([[3.0]]))[0, 0], "lands outside the view"
    row = np.array([[10.0, 20.0, 30.0, 40.0, 50.0], [7.0, 8.0, 9.0, 1.0, 2.0]])
    kept = np.array([[False, True, False, False, True], [False] * 5])
    assert fill_rejected(row, kept).tolist() == [[20, 20, 20, 20, 50], [0, 0, 0, 0, 0]]


def test_the_mirrored_head_reads_the_right_view() -> None:
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=8)).eval()
    dl, dr = torch.randn(6, 10, 8), torch.randn(6, 10, 8)
    with torch.no_grad():
        left, kept = head_lr(head, (dl, dr), mirror_descriptors(dl, dr))
        direct = head(dr.flip(1)[None], dl.flip(1)[None]).disparity[0].numpy()[:, ::-1]
        assert np.allclose(left, head(dl[None], dr[None]).disparity[0].numpy())
    assert kept.tolist() == consistent(left, direct).tolist()


def test_head_is_fully_convolutional() -> None:
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=8)).eval()
    dl, dr = torch.randn(1, 20, 30, 8), torch.randn(1, 20, 30, 8)
    with torch.no_grad():
        full = head(dl, dr).disparity
        top = head(dl[:, :12], dr[:, :12]).disparity
    assert full.shape == (1, 20, 30)
    # Away from the cut the receptive field (3 conv layers: 3 rows) sees the same rows.
    assert torch.allclose(full[:, :9], top[:, :9], atol=1e-5)


def test_learning_rate_warms_up_then_decays() -> None:
    cfg = HeadTrainConfig(lr=1e-3, min_lr=1e-5, warmup=0.1, schedule_steps=100)
    assert cosine_lr(0, cfg) == pytest.approx(1e-4)
    assert cosine_lr(9, cfg) == pytest.approx(1e-3)
    assert cosine_lr(100, cfg) == pytest.approx(1e-5)
    assert cosine_lr(10, cfg) > cosine_lr(50, cfg) > cosine_lr(90, cfg) > cosine_lr(1000, cfg) / 2


def test_config_round_trip() -> None:
    cfg = HeadTrainConfig(head=HeadConfig(max_disp=10), data=replace(TINY_DATA, max_disp=10))
    assert HeadTrainConfig.from_dict(cfg.to_dict()) == cfg
