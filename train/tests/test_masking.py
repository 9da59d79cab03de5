"""One-view masking of the student input."""

from __future__ import annotations

import pytest
import torch

from bino_train.masking import (
    MaskConfig,
    OneViewMasker,
    cells_to_pixels,
    fused_token_mask,
    mask_ratio,
    sample_cell_mask,
)


def _masked(cfg: MaskConfig, ratio: float, batch: int = 16, seed: int = 0):  # type: ignore[no-untyped-def]
    gen = torch.Generator().manual_seed(seed)
    left = torch.rand(batch, 1, 48, 160, generator=gen)
    right = torch.rand(batch, 1, 48, 160, generator=gen)
    return left, right, OneViewMasker(cfg, (4, 4), seed=seed)(left, right, ratio)


@pytest.mark.parametrize("block", [(1, 1), (2, 3)])
def test_mask_touches_exactly_one_view_and_only_masked_cells(block: tuple[int, int]) -> None:
    cfg = MaskConfig(block_h=block[0], block_w=block[1])
    left, right, out = _masked(cfg, 0.4)
    cells = out.token_mask[:, :, 0::2]  # (B, 12, 40) view-cell mask
    pixels = cells_to_pixels(cells, 4, 4)
    for b in range(left.shape[0]):
        changed_left = out.left[b] != left[b]
        changed_right = out.right[b] != right[b]
        masked_view = int(out.views[b])
        changed = (changed_left, changed_right)[masked_view]
        untouched = (changed_left, changed_right)[1 - masked_view]
        assert not bool(untouched.any())
        assert torch.equal(changed, pixels[b])  # every pixel of a masked cell, nothing else
        source = (left, right)[masked_view][b]
        filled = (out.left, out.right)[masked_view][b][pixels[b]]
        assert torch.allclose(filled, source.mean().expand_as(filled))
    assert set(out.views.tolist()) == {0, 1}


def test_fused_token_mask_marks_both_phases_of_a_masked_cell() -> None:
    _, _, out = _masked(MaskConfig(), 0.3)
    assert out.token_mask.shape == (16, 12, 80)
    assert torch.equal(out.token_mask[:, :, 0::2], out.token_mask[:, :, 1::2])
    assert torch.equal(fused_token_mask(out.token_mask[:, :, 0::2]), out.token_mask)


def test_unit_blocks_mask_an_exact_count() -> None:
    mask = sample_cell_mask(torch.Generator().manual_seed(1), 8, 12, 40, 0.25, (1, 1))
    assert mask.sum(dim=(1, 2)).tolist() == [120] * 8


def test_block_masks_come_in_blocks_and_near_the_ratio() -> None:
    mask = sample_cell_mask(torch.Generator().manual_seed(2), 64, 12, 40, 0.5, (2, 3))
    assert mask.shape == (64, 12, 40)
    assert abs(float(mask.float().mean()) - 0.5) < 0.05
    assert not torch.equal(mask[0], mask[1])


def test_mask_ratio_schedule_endpoints() -> None:
    cfg = MaskConfig(ratio_start=0.1, ratio_end=0.5)
    assert mask_ratio(0, 100, cfg) == pytest.approx(0.1)
    assert mask_ratio(50, 100, cfg) == pytest.approx(0.3)
    assert mask_ratio(100, 100, cfg) == pytest.approx(0.5)
    assert mask_ratio(500, 100, cfg) == pytest.approx(0.5)


def test_masker_state_restores_exactly() -> None:
    masker = OneViewMasker(MaskConfig(), (4, 4), seed=0)
    x = torch.rand(4, 1, 48, 160)
    masker(x, x, 0.3)
    state = masker.state_dict()
    first = masker(x, x, 0.3)
    other = OneViewMasker(MaskConfig(), (4, 4), seed=7)
    other.load_state_dict(state)
    second = other(x, x, 0.3)
    assert torch.equal(first.token_mask, second.token_mask)
    assert torch.equal(first.views, second.views)
