"""The ONNX export and the committed parity fixture agree with the PyTorch model."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from bino_train.export import export_onnx, main, output_names, random_encoder
from bino_train.model import stage_names

FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "fixtures"


def test_committed_fixture_matches_the_current_model() -> None:
    # If model.py changes, the committed ONNX + fixture must be regenerated (see export.py).
    folder = FIXTURES / "parity"
    encoder = random_encoder(0)
    left = torch.from_numpy(np.load(folder / "left.npy"))
    right = torch.from_numpy(np.load(folder / "right.npy"))
    with torch.no_grad():
        stages = dict(
            zip(stage_names(encoder.cfg), encoder.forward_stages(left, right), strict=True)
        )
    for name in ("embed", "tokens"):
        expected = np.load(folder / f"{name}.npy")
        assert np.abs(stages[name].numpy() - expected).max() < 1e-5, name


@pytest.mark.parametrize("height,width", [(48, 80), (32, 44)])
def test_onnx_with_intermediates_matches_torch_at_dynamic_sizes(
    tmp_path: Path, height: int, width: int
) -> None:
    encoder = random_encoder(3)
    path = tmp_path / "enc.onnx"
    export_onnx(encoder, path, intermediates=True, provenance="test")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == output_names(encoder.cfg, True)
    rng = np.random.default_rng(0)
    left = rng.random((1, 3, height, width), dtype=np.float32)
    right = rng.random((1, 3, height, width), dtype=np.float32)
    got = session.run(None, {"left": left, "right": right})
    with torch.no_grad():
        stages = encoder.forward_stages(torch.from_numpy(left), torch.from_numpy(right))
    want = [stages[-1], *stages[:-1]]
    assert len(got) == len(want) == 9
    for g, w in zip(got, want, strict=True):
        assert g.shape == (1, height // 4, width // 2, 128)
        assert np.abs(g - w.numpy()).max() < 1e-4


def test_random_init_is_refused_into_weights(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="refusing"):
        main(["--random-init-seed", "0", "--out", str(tmp_path / "weights" / "x.onnx")])


@pytest.mark.parametrize("height,width", [(48, 80), (32, 44)])
def test_row_attention_exports_its_mask_at_dynamic_sizes(
    tmp_path: Path, height: int, width: int
) -> None:
    """`--attention-rows 0`: the graph holds each token row to itself at every band size,
    and stamps the reach into `bino.config` for the quantiser."""
    path = tmp_path / "enc.onnx"
    main(["--random-init-seed", "3", "--attention-rows", "0", "--out", str(path)])
    encoder = random_encoder(3)
    encoder.cfg = dataclasses.replace(encoder.cfg, attention_rows=0)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(1)
    left = rng.random((1, 3, height, width), dtype=np.float32)
    right = rng.random((1, 3, height, width), dtype=np.float32)
    (got,) = session.run(None, {"left": left, "right": right})
    with torch.no_grad():
        want = encoder(torch.from_numpy(left), torch.from_numpy(right)).numpy()
    assert np.abs(got - want).max() < 1e-4
    config = {p.key: p.value for p in onnx.load(str(path)).metadata_props}["bino.config"]
    assert "'attention_rows': 0" in config


def test_row_embedding_option_gives_every_row_one_embedding(tmp_path: Path) -> None:
    state = tmp_path / "enc.pt"
    args = ["--random-init-seed", "4", "--attention-rows", "0", "--out", str(tmp_path / "e.onnx")]
    main([*args, "--row-embedding", "5", "--state-dict", str(state)])
    rows = torch.load(state, weights_only=False)["encoder"]["row_embed"]
    assert torch.equal(rows, rows[5:6].expand_as(rows))
    assert not torch.equal(rows, random_encoder(4).row_embed.detach())
    with pytest.raises(SystemExit):
        main([*args, "--row-embedding", "12"])


def test_negative_attention_rows_are_refused_by_the_exporter(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        main(
            ["--random-init-seed", "0", "--attention-rows", "-1", "--out", str(tmp_path / "x.onnx")]
        )
