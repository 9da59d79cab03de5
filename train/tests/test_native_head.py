"""The native pathway: phase maps of one encoder pass on (L, R), the native head (pair features,
two projections), its budget, ONNX export, cache pathway checks and the left-right check on the
encoder's pass over the mirrored pair."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from conftest import TINY_SYNTHETIC_DATA, cpu_trainer, save_tiny_cache
from torch.utils.flop_counter import FlopCounterMode

from bino_train.config import PAPER_CONFIG
from bino_train.export import random_encoder
from bino_train.head import (
    NATIVE_FULL_HEAD,
    NATIVE_HEAD,
    PAPER_HEAD,
    HeadConfig,
    NativeHead,
    StereoHead,
    export_head_onnx,
    head_macs,
    load_head,
    make_head,
    write_native_fixture,
)
from bino_train.head_cache import cache_pathway
from bino_train.head_data import HeadSampler, encode
from bino_train.head_eval import consistent, diagonal_right, evaluate_head, head_lr, pair_inputs
from bino_train.head_train import SMOKE_ENCODER, SMOKE_HEAD, HeadTrainConfig, main
from bino_train.head_val import ValidationSet
from bino_train.model import BinoEncoder, encoder_macs, parameter_count, phase_maps
from bino_train.probe import encoder_phase_maps

TINY_NATIVE = replace(SMOKE_HEAD, desc_dim=SMOKE_ENCODER.dim, pair_features="concat")

PARAMETER_BUDGET = 200_000
MAC_BUDGET = 0.15
"""Issue 15: at most 0.2M parameters and 15 % of one encoder pass's MACs at 48x160."""

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _encoder() -> BinoEncoder:
    return random_encoder(0, SMOKE_ENCODER).eval()


def _gray(seed: int, h: int, w: int) -> np.ndarray:
    return np.random.default_rng(seed).random((h, w), dtype=np.float32)


def test_phase_maps_are_the_even_and_odd_fused_columns() -> None:
    enc = _encoder()
    left, right = (
        torch.from_numpy(_gray(s, 48, 64))[None, None].expand(-1, 3, -1, -1) for s in (1, 2)
    )
    with torch.no_grad():
        tokens = enc(left, right)
        even, odd = enc.phase_maps(left, right)
    assert even.shape == odd.shape == (1, 12, 16, SMOKE_ENCODER.dim)
    assert torch.equal(even[:, :, 3], tokens[:, :, 6]) and torch.equal(
        odd[:, :, 3], tokens[:, :, 7]
    )
    assert [t.shape for t in phase_maps(tokens)] == [even.shape, odd.shape]


def test_native_encoding_is_one_pass_on_the_pair() -> None:
    enc = _encoder()
    samples = HeadSampler(TINY_SYNTHETIC_DATA, seed=0, data_dir=None).samples(range(3))
    native = encode(enc, samples, torch.device("cpu"), "native")
    export = encode(enc, samples, torch.device("cpu"), "export")
    s = samples[1]
    pair = [torch.from_numpy(v)[None, None].expand(-1, 3, -1, -1) for v in (s.left, s.right)]
    with torch.no_grad():
        even, odd = enc.phase_maps(*pair)
        dl = enc.descriptors(pair[0])
    assert torch.allclose(native.left[1], even[0], atol=1e-5)
    assert torch.allclose(native.right[1], odd[0], atol=1e-5)
    assert torch.allclose(export.left[1], dl[0], atol=1e-5)  # the export pathway as before
    assert torch.equal(native.label.nan_to_num(-1), export.label.nan_to_num(-1))
    assert not torch.allclose(native.left, export.left)
    with pytest.raises(ValueError, match="pathway"):
        encode(enc, samples, torch.device("cpu"), "fused")


def test_encoder_macs_match_torchs_flop_count() -> None:
    enc = BinoEncoder(PAPER_CONFIG).eval()
    x = torch.zeros(1, 3, 48, 160)
    with FlopCounterMode(display=False) as counter, torch.no_grad():
        enc(x, x)
    assert counter.get_total_flops() == 2 * encoder_macs(PAPER_CONFIG, 48, 160)
    assert round(encoder_macs(PAPER_CONFIG) / 1e9, 2) == 2.92  # README: 2.92 GMAC a pass


@pytest.mark.parametrize("cfg", [PAPER_HEAD, NATIVE_HEAD, NATIVE_FULL_HEAD])
def test_head_macs_match_torchs_flop_count(cfg: HeadConfig) -> None:
    head = make_head(cfg).eval()
    x = torch.zeros(1, 12, 40, cfg.desc_dim)
    with FlopCounterMode(display=False) as counter, torch.no_grad():
        head(x, x)
    # torch counts the group pooling as a dense MatMul over all groups; head_macs counts each
    # product once (summed into its own group).
    cells_k = 12 * 40 * cfg.max_disp
    pooled = cells_k * cfg.proj_dim * cfg.groups - cells_k * cfg.proj_dim
    assert counter.get_total_flops() // 2 - pooled == head_macs(cfg, 12, 40)


@pytest.mark.parametrize("cfg", [NATIVE_HEAD, NATIVE_FULL_HEAD])
def test_native_heads_fit_the_budget(cfg: HeadConfig) -> None:
    params = parameter_count(make_head(cfg))
    assert parameter_count(StereoHead()) == 85_985
    assert params <= PARAMETER_BUDGET, params
    share = head_macs(cfg) / encoder_macs(PAPER_CONFIG)
    assert share <= MAC_BUDGET, share
    # The shared head's 96 channels on u = [a, b] would be over the MAC budget.
    wide = replace(cfg, proj_dim=96)
    assert head_macs(wide) / encoder_macs(PAPER_CONFIG) > MAC_BUDGET


def _standard(x: torch.Tensor) -> torch.Tensor:
    return (x - x.mean(-1, keepdim=True)) / x.std(-1, unbiased=False, keepdim=True)


@pytest.mark.parametrize("shift", [0, 2, 5, 9])
def test_two_projections_correlate_left_features_with_shifted_right_features(shift: int) -> None:
    # u = [a, b] standardised, so LayerNorm is the identity. P_L reads a, P_R reads b; with
    # b[q] = a[q + shift] the correlation f_L[p] * f_R[p - k] peaks at k = shift.
    cfg = replace(NATIVE_HEAD, desc_dim=32, proj_dim=32, groups=8)
    head = NativeHead(cfg).eval()
    t, p = 4, 24
    torch.manual_seed(shift)
    z = _standard(torch.randn(1, t, p + shift, 32))
    even, odd = z[:, :, :p], z[:, :, shift : shift + p]
    with torch.no_grad():
        eye = torch.eye(32)
        head.proj_left.weight.copy_(torch.cat([eye, torch.zeros(32, 32)], dim=1))
        head.proj_right.weight.copy_(torch.cat([torch.zeros(32, 32), eye], dim=1))
        head.proj_left.bias.zero_()
        head.proj_right.bias.zero_()
        corr = head.correlation(*head.features(even, odd)).sum(dim=1)[0]
    assert torch.all(corr.argmax(dim=0)[:, shift:] == shift)


def test_full_pair_features_are_a_b_absdiff_product() -> None:
    head = NativeHead(replace(NATIVE_FULL_HEAD, desc_dim=8, proj_dim=16, groups=4)).eval()
    a, b = torch.randn(2, 3, 5, 8), torch.randn(2, 3, 5, 8)
    with torch.no_grad():
        u = head.pair_features(a, b)
        expected = head.norm(torch.cat([a, b, (a - b).abs(), a * b], dim=-1))
    assert u.shape == (2, 3, 5, 32) and torch.allclose(u, expected, atol=1e-6)


def test_native_init_is_pca_of_the_pair_features() -> None:
    head = NativeHead(replace(TINY_NATIVE, proj_dim=8, groups=4))
    torch.manual_seed(0)
    a = torch.randn(4, 6, 10, SMOKE_ENCODER.dim) + 3.0  # a large common vector, as the encoder's
    b = torch.randn(4, 6, 10, SMOKE_ENCODER.dim) - 1.0
    head.init_from(a, b)
    assert torch.equal(head.proj_left.weight, head.proj_right.weight)
    with torch.no_grad():
        f_left, _ = head.features(a, b)
    flat = f_left.reshape(-1, 8)
    assert flat.mean(0).abs().max() < 1e-4  # centred
    assert float(flat.var(0).mean()) == pytest.approx(1.0, rel=0.01)  # unit mean variance
    assert float(flat.var(0)[0]) > float(flat.var(0)[-1])  # top principal direction first
    with pytest.raises(TypeError):
        head.init_projection(a)
    with pytest.raises(TypeError):
        head.project(a)  # one shared projection is the export head's


@pytest.mark.parametrize("cfg", [NATIVE_HEAD, NATIVE_FULL_HEAD])
def test_native_onnx_export_matches_torch_in_the_op_set(tmp_path: Path, cfg: HeadConfig) -> None:
    torch.manual_seed(1)
    head = make_head(cfg).eval()
    path = tmp_path / "native.onnx"
    export_head_onnx(head, path, provenance="test", logits=True)
    model = onnx.load(str(path))
    ops = {node.op_type for node in model.graph.node}
    allowed = {"LayerNormalization", "MatMul", "Add", "Sub", "Mul", "Concat", "Slice"}
    allowed |= {"Unsqueeze", "Squeeze", "Transpose", "Conv", "Relu", "Softmax", "ReduceSum"}
    allowed |= {"ReduceMax", "Constant", "Identity"}
    assert ops <= allowed, ops - allowed
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["bino.pathway"] == "native"
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["phase_even", "phase_odd"]
    rng = np.random.default_rng(0)
    a, b = (rng.normal(size=(1, 7, 19, 128)).astype(np.float32) for _ in range(2))
    got = session.run(None, {"phase_even": a, "phase_odd": b})
    with torch.no_grad():
        out = head(torch.from_numpy(a), torch.from_numpy(b))
    assert np.abs(got[0] - out.disparity.numpy()).max() < 1e-4
    assert np.abs(got[2] - out.logits.numpy()).max() < 1e-3


def test_shared_head_checkpoints_keep_their_format(tmp_path: Path) -> None:
    head = StereoHead()
    assert "pair_features" not in PAPER_HEAD.to_dict()
    keys = list(head.state_dict())
    assert keys[:4] == ["norm.weight", "norm.bias", "proj.weight", "proj.bias"]
    assert keys[4] == "stem.weight" and keys[-1] == "out.bias"
    old = {k: v for k, v in PAPER_HEAD.to_dict().items()}  # as written before native heads
    torch.save({"head_config": old, "head": head.state_dict()}, tmp_path / "old.pt")
    loaded = load_head(tmp_path / "old.pt")
    assert type(loaded) is StereoHead and loaded.cfg == PAPER_HEAD
    native = NativeHead(NATIVE_HEAD)
    torch.save(
        {"head_config": NATIVE_HEAD.to_dict(), "head": native.state_dict()}, tmp_path / "n.pt"
    )
    assert isinstance(load_head(tmp_path / "n.pt"), NativeHead)
    with pytest.raises(ValueError):
        StereoHead(NATIVE_HEAD)
    with pytest.raises(ValueError):
        HeadConfig(pair_features="sum")


def test_phase_maps_of_tall_images_are_stitched_from_bands() -> None:
    enc = _encoder()
    left, right = _gray(3, 80, 64), _gray(4, 80, 64)
    even, odd = encoder_phase_maps(enc, left, right)
    assert even.shape == odd.shape == (20, 16, SMOKE_ENCODER.dim)
    view = [
        torch.from_numpy(v[:48].copy())[None, None].expand(-1, 3, -1, -1) for v in (left, right)
    ]
    with torch.no_grad():
        top_even, _ = enc.phase_maps(*view)
    assert torch.allclose(even[:8], top_even[0, :8], atol=1e-5)  # first band's kept rows


def test_native_pair_inputs_and_its_one_pass_check() -> None:
    enc = _encoder()
    head = NativeHead(TINY_NATIVE).eval()
    left, right = _gray(5, 32, 64), _gray(6, 32, 64)
    inputs, mirrored = pair_inputs(enc, "native", left, right)
    expected = encoder_phase_maps(enc, right[:, ::-1].copy(), left[:, ::-1].copy())
    assert all(torch.equal(m, e) for m, e in zip(mirrored, expected, strict=True))
    assert not torch.allclose(mirrored[0], inputs[1].flip(1))  # not the mirrored phase maps
    with torch.no_grad():
        disparity, kept = head_lr(head, inputs, mirrored)
        out = head(inputs[0][None], inputs[1][None])
    direct = out.disparity[0].numpy()
    assert np.allclose(disparity, direct) and kept.shape == disparity.shape
    # The native check reads the right view from the same logits: no second pass.
    right = diagonal_right(out.logits[0].double().numpy())
    assert np.array_equal(kept, consistent(disparity, right))


def test_the_diagonal_reads_a_consistent_scene_from_the_right() -> None:
    """Every left cell sure of disparity 2, a nearer object (4) on cells 6..8. Right cell q
    is read from left cells q + k at k: where the background and the object both land the
    equal peaks average, where nothing lands (occluded, or the right edge) the logits are flat."""
    d, cols = 6, 12
    disparity = np.array([4 if 6 <= p < 9 else 2 for p in range(cols)])
    logits = np.full((d, 1, cols), -50.0)
    logits[disparity, 0, np.arange(cols)] = 50.0
    right = diagonal_right(logits)[0]
    # 0-1 background; 2-3 background and object; 4 object; 5-6 nothing (k 0..5 flat);
    # 7-9 background; 10 only k 0..1 inside the row; 11 only k 0.
    expected = [2, 2, 3, 3, 4, 2.5, 2.5, 2, 2, 2, 0.5, 0]
    assert np.allclose(right, expected, atol=1e-6), right
    kept = consistent(disparity[None].astype(np.float32), right[None])[0]
    # Cells 0-1 land outside the right view; the rest agree within one column.
    assert kept.tolist() == [False, False] + [True] * 10


def test_a_cache_trains_only_its_own_pathway(tmp_path: Path) -> None:
    enc = _encoder()
    path = tmp_path / "native.pt"
    save_tiny_cache(path, enc, TINY_SYNTHETIC_DATA, 0, 6, pathway="native")
    assert cache_pathway(json.loads((tmp_path / "native.pt.json").read_text())) == "native"
    assert cache_pathway({}) == "export"  # caches from before the native pathway
    native = HeadTrainConfig(head=TINY_NATIVE, data=TINY_SYNTHETIC_DATA, batch=4, cache=str(path))
    trainer = cpu_trainer(native, enc)
    first = trainer.train_step()
    assert np.isfinite(first["loss"]) and isinstance(trainer.head, NativeHead)
    export = replace(native, head=replace(TINY_NATIVE, pair_features=""))
    with pytest.raises(
        ValueError, match="native-pathway maps, this run trains a head of the export pathway"
    ):
        cpu_trainer(export, enc)
    with pytest.raises(SystemExit, match="--pathway native"):
        main(
            ["--random-init-seed", "0", "--out", str(tmp_path / "r"), "--cache", str(path)]
            + ["--steps", "1"]
        )


def test_native_smoke_run_reduces_the_loss(tmp_path: Path) -> None:
    out = tmp_path / "smoke"
    with pytest.raises(SystemExit) as exit_info:
        main(["--random-init-seed", "0", "--out", str(out), "--smoke", "--pathway", "native"])
    assert exit_info.value.code == 0
    state = torch.load(out / "last.pt", weights_only=False)
    assert state["head_config"]["pair_features"] == "concat"
    assert isinstance(load_head(out / "last.pt"), NativeHead)


def test_validation_and_evaluation_score_native_heads(data_dir: Path) -> None:
    enc = _encoder()
    head = NativeHead(TINY_NATIVE)
    val = ValidationSet.build(
        enc, data_dir, TINY_SYNTHETIC_DATA, synthetic_count=4, pathway="native"
    )
    scores = val.score(head)
    assert np.isfinite(scores["val_synthetic"]["epe"])
    with pytest.raises(ValueError, match="export-pathway head on a native"):
        val.score(StereoHead(replace(SMOKE_HEAD, desc_dim=SMOKE_ENCODER.dim)))
    result = evaluate_head(enc, head, data_dir)
    assert result["pathway"] == "native" and result["probe"] is None
    assert np.isfinite(result["head+lr"]["epe"]) and result["pairs"] == 2


def test_native_fixture_is_a_concat_head_with_logits(tmp_path: Path) -> None:
    out = tmp_path / "native.onnx"
    write_native_fixture(out)
    model = onnx.load(str(out))
    assert [i.name for i in model.graph.input] == ["phase_even", "phase_odd"]
    assert [o.name for o in model.graph.output] == ["disparity", "confidence", "logits"]
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["bino.pathway"] == "native" and "'concat'" in meta["bino.head_config"]
    names = {n.name for n in model.graph.node}
    assert {"/head/proj_left/Add", "/head/proj_right/Add"} <= names
    phases = np.random.default_rng(0).normal(size=(2, 1, 12, 40, 128)).astype(np.float32)
    session = ort.InferenceSession(str(out))
    disparity, _, logits = session.run(None, {"phase_even": phases[0], "phase_odd": phases[1]})
    assert logits.shape == (1, 12, 12, 40) and np.isfinite(disparity).all()
    with pytest.raises(SystemExit):
        write_native_fixture(tmp_path / "weights" / "native.onnx")
