"""One-view patch masking of the student's input (paper section 3.4).

For each sample one view, chosen at random, loses a set of its 4x4 view cells (token row r,
patch column p); the other view stays intact, so the student has to recover the missing
content from the complementary view. Cells may be masked in blocks of (bh x bw) cells.

The masked pixels are replaced by the mean of that view (per sample). That keeps the encoder
and its ONNX graph unchanged (no learnable mask token) and makes a masked cell look like a
flat, textureless area rather than a black hole with a tell-tale edge.

Each masked view cell feeds both phase tokens c = 2p and c = 2p + 1 of the fused grid (a
token holds a 4x2 micro-cell of each view), so the fused-grid mask marks both.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor


@dataclass(frozen=True)
class MaskConfig:
    ratio_start: float = 0.1
    ratio_end: float = 0.5
    block_h: int = 1
    block_w: int = 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def mask_ratio(step: float, total_steps: int, cfg: MaskConfig) -> float:
    """Linear from `ratio_start` at step 0 to `ratio_end` at `total_steps` (then held)."""
    progress = min(max(step / max(total_steps, 1), 0.0), 1.0)
    return cfg.ratio_start + (cfg.ratio_end - cfg.ratio_start) * progress


def sample_cell_mask(
    gen: torch.Generator, batch: int, rows: int, cols: int, ratio: float, block: tuple[int, int]
) -> Tensor:
    """(B, rows, cols) bool. With 1x1 blocks exactly round(ratio * rows * cols) cells per sample;
    with larger blocks, round(ratio * n) blocks of a randomly offset block grid."""
    bh, bw = block
    nbr = math.ceil(rows / bh) + (1 if bh > 1 else 0)
    nbc = math.ceil(cols / bw) + (1 if bw > 1 else 0)
    count = round(ratio * nbr * nbc)
    noise = torch.rand(batch, nbr * nbc, generator=gen)
    chosen = noise.argsort(dim=1)[:, :count]
    blocks = torch.zeros(batch, nbr * nbc, dtype=torch.bool).scatter_(1, chosen, True)
    cells = blocks.view(batch, nbr, nbc).repeat_interleave(bh, 1).repeat_interleave(bw, 2)
    oy = torch.randint(0, bh, (batch,), generator=gen)
    ox = torch.randint(0, bw, (batch,), generator=gen)
    # The random offset shifts the block grid so block edges fall anywhere in the crop.
    return torch.stack([cells[b, oy[b] : oy[b] + rows, ox[b] : ox[b] + cols] for b in range(batch)])


def cells_to_pixels(cell_mask: Tensor, cell_h: int, cell_w: int) -> Tensor:
    """(B, rows, cols) -> (B, 1, rows * cell_h, cols * cell_w)."""
    return cell_mask.repeat_interleave(cell_h, 1).repeat_interleave(cell_w, 2)[:, None]


def fused_token_mask(cell_mask: Tensor) -> Tensor:
    """(B, rows, P) view-cell mask -> (B, rows, 2P) fused-grid mask (both phases of a cell)."""
    return cell_mask.repeat_interleave(2, dim=2)


def apply_one_view_mask(
    left: Tensor, right: Tensor, cell_mask: Tensor, views: Tensor, cell: tuple[int, int]
) -> tuple[Tensor, Tensor]:
    """Replace the masked cells of view `views[b]` (0 left, 1 right) by that view's mean."""
    pixels = cells_to_pixels(cell_mask.to(left.device), *cell)
    views = views.to(left.device).view(-1, 1, 1, 1)
    out = []
    for index, view in enumerate((left, right)):
        mean = view.mean(dim=(1, 2, 3), keepdim=True)
        out.append(torch.where(pixels & (views == index), mean, view))
    return out[0], out[1]


class MaskedPair(NamedTuple):
    left: Tensor
    right: Tensor
    token_mask: Tensor
    """(B, rows, 2P) bool on the fused token grid."""
    views: Tensor
    """(B,) which view was masked: 0 left, 1 right."""


class OneViewMasker:
    """Draws masks from its own generator, so its state can be checkpointed."""

    def __init__(self, cfg: MaskConfig, cell: tuple[int, int], seed: int) -> None:
        self.cfg = cfg
        self.cell = cell
        self.gen = torch.Generator().manual_seed(seed)

    def __call__(self, left: Tensor, right: Tensor, ratio: float) -> MaskedPair:
        b, _, h, w = left.shape
        rows, cols = h // self.cell[0], w // self.cell[1]
        block = (self.cfg.block_h, self.cfg.block_w)
        cell_mask = sample_cell_mask(self.gen, b, rows, cols, ratio, block)
        views = torch.randint(0, 2, (b,), generator=self.gen)
        s_left, s_right = apply_one_view_mask(left, right, cell_mask, views, self.cell)
        return MaskedPair(s_left, s_right, fused_token_mask(cell_mask), views)

    def state_dict(self) -> dict[str, Any]:
        return {"gen": self.gen.get_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.gen.set_state(state["gen"])
