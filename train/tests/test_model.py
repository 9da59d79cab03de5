"""Properties the paper's architecture promises, each checked so that a wrong model fails."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from bino_train.config import EncoderConfig
from bino_train.model import (
    BinoEncoder,
    apply_rope,
    encoder_macs,
    interleave,
    parameter_count,
    phase_average,
    rope_positions,
    rope_tables,
    row_window_mask,
    uniform_row_embedding,
)

CFG = EncoderConfig()


def test_interleave_puts_left_on_even_and_right_on_odd_columns() -> None:
    left = torch.arange(2 * 3 * 4 * 5, dtype=torch.float32).reshape(2, 3, 4, 5)
    right = -left - 1
    fused = interleave(left, right)
    assert fused.shape == (2, 3, 4, 10)
    for u in range(5):
        assert torch.equal(fused[..., 2 * u], left[..., u])
        assert torch.equal(fused[..., 2 * u + 1], right[..., u])


def test_interleave_rejects_mismatched_views() -> None:
    with pytest.raises(ValueError, match="differ"):
        interleave(torch.zeros(1, 3, 4, 8), torch.zeros(1, 3, 4, 12))


def test_patch_token_is_a_4x2_micro_cell_of_each_view() -> None:
    """Changing one view pixel changes exactly the token whose micro-cell holds it."""
    model = BinoEncoder(CFG).eval()
    left = torch.rand(1, 3, 8, 16)
    right = torch.rand(1, 3, 8, 16)
    base = model.patch_embed(interleave(left, right))
    right2 = right.clone()
    right2[0, :, 5, 6] += 1.0  # view column 6 -> patch column 1, phase 1; row 5 -> token row 1
    changed = (model.patch_embed(interleave(left, right2)) - base).abs().sum(dim=1)[0]
    assert changed.nonzero().tolist() == [[1, 3]]  # fused column c = 2 * 1 + 1


def test_two_phase_tokens_of_a_cell_share_the_rope_column() -> None:
    rows, cols = rope_positions(torch.arange(3), torch.arange(8))
    grid_p = cols.reshape(3, 8)
    assert torch.equal(grid_p[:, 0::2], grid_p[:, 1::2])
    assert torch.equal(grid_p[0], torch.tensor([0, 0, 1, 1, 2, 2, 3, 3]))
    assert torch.equal(rows.reshape(3, 8)[:, 0], torch.arange(3))
    cos, sin = rope_tables(rows, cols, CFG.head_dim, CFG.rope_base)
    x = torch.randn(CFG.head_dim)
    rotated = apply_rope(x.expand(24, -1), cos, sin).reshape(3, 8, -1)
    assert torch.allclose(rotated[:, 0::2], rotated[:, 1::2])
    assert not torch.allclose(rotated[:, 0], rotated[:, 2])


def _logit(q: torch.Tensor, k: torch.Tensor, qpos: tuple[int, int], kpos: tuple[int, int]) -> float:
    rows = torch.tensor([qpos[0], kpos[0]])
    cols = torch.tensor([qpos[1], kpos[1]])
    cos, sin = rope_tables(rows, cols, CFG.head_dim, CFG.rope_base)
    qr = apply_rope(q, cos[0], sin[0])
    kr = apply_rope(k, cos[1], sin[1])
    return float((qr * kr).sum())


def test_attention_logits_depend_only_on_relative_row_and_column() -> None:
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(CFG.head_dim, generator=gen)
    k = torch.randn(CFG.head_dim, generator=gen)
    reference = _logit(q, k, (2, 5), (4, 1))
    for shift in ((0, 3), (5, 0), (7, 11), (-2, -1)):
        moved = _logit(q, k, (2 + shift[0], 5 + shift[1]), (4 + shift[0], 1 + shift[1]))
        assert moved == pytest.approx(reference, abs=1e-4)
    # A different relative offset must give a different logit, in rows and in columns.
    assert abs(_logit(q, k, (2, 5), (4, 2)) - reference) > 1e-3
    assert abs(_logit(q, k, (2, 5), (5, 1)) - reference) > 1e-3


def test_descriptor_shape_and_phase_average() -> None:
    model = BinoEncoder(CFG).eval()
    image = torch.rand(1, 3, 48, 160)
    with torch.no_grad():
        desc = model.descriptors(image)
        tokens = model(image, image)
    assert desc.shape == (1, 12, 40, 128)
    assert tokens.shape == (1, 12, 80, 128)
    assert torch.allclose(desc[0, 3, 7], 0.5 * (tokens[0, 3, 14] + tokens[0, 3, 15]))
    assert torch.allclose(phase_average(tokens), desc)


def test_output_is_de_positioned() -> None:
    model = BinoEncoder(CFG).eval()
    image = torch.rand(1, 3, 16, 32)
    with torch.no_grad():
        stages = model.forward_stages(image, image)
        expected = stages[-2] - model.row_embed[:4].reshape(1, 4, 1, -1)
    assert torch.allclose(stages[-1], expected)


def test_parameter_count_is_within_one_percent_of_paper() -> None:
    n = parameter_count(BinoEncoder(CFG))
    assert abs(n - 1.34e6) / 1.34e6 < 0.01, n


def test_encoder_rejects_bad_sizes() -> None:
    model = BinoEncoder(CFG)
    with pytest.raises(ValueError, match="height"):
        model.check_input(torch.zeros(1, 3, 50, 16), torch.zeros(1, 3, 50, 16))
    with pytest.raises(ValueError, match="width"):
        model.check_input(torch.zeros(1, 3, 48, 18), torch.zeros(1, 3, 48, 18))
    with pytest.raises(ValueError, match="differ"):
        model.check_input(torch.zeros(1, 3, 48, 16), torch.zeros(1, 3, 48, 20))


def test_row_attention_keeps_each_token_row_to_its_own_pixel_rows() -> None:
    """With attention_rows=0 a token row reads only its own four pixel rows (and its row
    embedding); with attention over the band, redrawing one row changes every row."""
    torch.manual_seed(0)
    band = BinoEncoder(CFG).eval()
    row = BinoEncoder(dataclasses.replace(CFG, attention_rows=0)).eval()
    row.load_state_dict(band.state_dict())
    left, right = torch.rand(1, 3, 16, 32), torch.rand(1, 3, 16, 32)
    left2 = left.clone()
    left2[..., 8:12, :] = torch.rand(1, 3, 4, 32)
    with torch.no_grad():
        changed_row = (row(left, right) - row(left2, right)).abs().amax(dim=(0, 2, 3))
        changed_band = (band(left, right) - band(left2, right)).abs().amax(dim=(0, 2, 3))
    assert changed_row[2] > 0
    assert torch.all(changed_row[[0, 1, 3]] == 0)
    assert torch.all(changed_band > 0)


def test_one_row_embedding_makes_a_token_row_independent_of_its_place() -> None:
    """Row attention and one row embedding for every row: a token row's output is the same
    whether its band starts at it or above it (what lets a frame's bands share rows); with the
    trained per-row embeddings it is not."""
    torch.manual_seed(1)
    model = BinoEncoder(dataclasses.replace(CFG, attention_rows=0)).eval()
    left, right = torch.rand(1, 3, 24, 32), torch.rand(1, 3, 24, 32)
    with torch.no_grad():
        per_row = (model(left, right)[:, 2:], model(left[..., 8:, :], right[..., 8:, :]))
        uniform_row_embedding(model, 6)
        shared = (model(left, right)[:, 2:], model(left[..., 8:, :], right[..., 8:, :]))
    assert (per_row[0] - per_row[1]).abs().max() > 1e-3
    assert (shared[0] - shared[1]).abs().max() < 1e-5
    assert torch.equal(model.row_embed[0], model.row_embed[11])
    with pytest.raises(ValueError, match="outside"):
        uniform_row_embedding(model, 12)


def test_row_window_mask_allows_the_rows_within_reach() -> None:
    mask = row_window_mask(3, 2, 1, torch.device("cpu"))
    assert mask is not None and mask.shape == (6, 6)
    rows = torch.tensor([0, 0, 1, 1, 2, 2])
    assert torch.equal(mask, (rows[:, None] - rows[None, :]).abs() <= 1)
    assert row_window_mask(3, 2, None, torch.device("cpu")) is None


def test_row_attention_costs_a_twelfth_of_the_bands_attention_products() -> None:
    rows = dataclasses.replace(CFG, attention_rows=0)
    d, tokens, cols = CFG.dim, 12 * 80, 80
    saved = 7 * 2 * d * (tokens * tokens - tokens * cols)
    assert encoder_macs(CFG) - encoder_macs(rows) == saved


def test_negative_attention_rows_are_refused() -> None:
    with pytest.raises(ValueError, match="attention rows"):
        EncoderConfig(attention_rows=-1)
