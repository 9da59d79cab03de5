"""Model configuration: the paper-faithful defaults fixed in DESIGN.md."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class EncoderConfig:
    """Shape of the BINO encoder.

    The fused image is 3 x H x 2W; a `patch_h` x `patch_w` patch of it is a
    `patch_h` x `patch_w / 2` stereo micro-cell of each view.
    """

    dim: int = 128
    depth: int = 7
    heads: int = 4
    mlp_hidden: int = 480
    in_chans: int = 3
    patch_h: int = 4
    patch_w: int = 4
    band_rows: int = 48
    """Image rows the encoder sees at once; taller images go by overlapping bands."""
    rope_base: float = 100.0
    ln_eps: float = 1e-5
    attention_rows: int | None = None
    """Each token attends to the token rows within this many of its own (None: the whole band)."""

    def __post_init__(self) -> None:
        if self.dim % self.heads != 0:
            raise ValueError(f"dim {self.dim} is not divisible by heads {self.heads}")
        if self.head_dim % 4 != 0:
            raise ValueError(f"head dim {self.head_dim} must split into two even RoPE halves")
        if self.patch_w % 2 != 0:
            raise ValueError(f"fused patch width {self.patch_w} must be even")
        if self.band_rows % self.patch_h != 0:
            raise ValueError(f"band rows {self.band_rows} not a multiple of {self.patch_h}")
        if self.attention_rows is not None and self.attention_rows < 0:
            raise ValueError(f"attention rows {self.attention_rows} must be at least 0")

    @property
    def head_dim(self) -> int:
        return self.dim // self.heads

    @property
    def token_rows(self) -> int:
        """Token rows per band: the size of the learnable row-embedding table."""
        return self.band_rows // self.patch_h

    @property
    def view_cell_w(self) -> int:
        """Width in view pixels of one patch column (4 for the 4x4 fused patch)."""
        return self.patch_w

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


PAPER_CONFIG = EncoderConfig()
