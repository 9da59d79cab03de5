"""Weight-space interpolation of two head checkpoints (`head_interpolate`)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bino_train.head import NATIVE_HEAD, PAPER_HEAD, load_head, make_head
from bino_train.head_interpolate import interpolate_checkpoints, interpolate_states, main


def checkpoint(path: Path, seed: int, config: object = NATIVE_HEAD) -> Path:
    torch.manual_seed(seed)
    head = make_head(config)  # type: ignore[arg-type]
    state = {
        "head_config": vars(config).copy(),
        "head": head.state_dict(),
        "optimizer": {"state": {}},
        "step": seed,
    }
    torch.save(state, path)
    return path


def test_states_are_mixed_by_alpha_and_counters_come_from_the_end() -> None:
    start = {"w": torch.zeros(3), "n": torch.tensor(1)}
    end = {"w": torch.tensor([2.0, 4.0, 6.0]), "n": torch.tensor(7)}
    mid = interpolate_states(start, end, 0.25)
    assert torch.allclose(mid["w"], torch.tensor([0.5, 1.0, 1.5]))
    assert int(mid["n"]) == 7
    with pytest.raises(ValueError, match="shapes"):
        interpolate_states({"w": torch.zeros(2)}, {"w": torch.zeros(3)}, 0.5)
    with pytest.raises(ValueError, match="differ in their tensors"):
        interpolate_states({"w": torch.zeros(2)}, {"v": torch.zeros(2)}, 0.5)


def test_the_midpoint_loads_as_a_head_between_its_ends(tmp_path: Path) -> None:
    a = checkpoint(tmp_path / "a.pt", 1)
    b = checkpoint(tmp_path / "b.pt", 2)
    out = tmp_path / "mid" / "last.pt"
    main(["--start", str(a), "--end", str(b), "--alpha", "0.5", "--out", str(out)])
    mid = load_head(out)
    ha, hb = load_head(a), load_head(b)
    for (name, m), pa, pb in zip(
        mid.state_dict().items(), ha.state_dict().values(), hb.state_dict().values(), strict=True
    ):
        if m.is_floating_point():
            assert torch.allclose(m, (pa + pb) / 2), name
    state = torch.load(out, weights_only=False)
    assert "optimizer" not in state and state["step"] == 2
    assert state["interpolated"]["alpha"] == 0.5
    # alpha 1 is the end itself.
    end = interpolate_checkpoints(a, b, 1.0)["head"]
    assert all(torch.equal(end[k], v) for k, v in hb.state_dict().items())


def test_different_architectures_and_bad_alphas_are_errors(tmp_path: Path) -> None:
    a = checkpoint(tmp_path / "a.pt", 1)
    b = checkpoint(tmp_path / "b.pt", 2, PAPER_HEAD)
    with pytest.raises(ValueError, match="different head architectures"):
        interpolate_checkpoints(a, b, 0.5)
    with pytest.raises(ValueError, match="outside"):
        interpolate_checkpoints(a, a, 1.5)
    with pytest.raises(SystemExit, match="error: .*missing.pt"):
        main(
            [
                "--start",
                str(tmp_path / "missing.pt"),
                "--end",
                str(a),
                "--out",
                str(tmp_path / "o.pt"),
            ]
        )
