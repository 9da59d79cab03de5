"""The BINO float encoder (paper section 3.1-3.2).

Data flow: pixel interleave -> 4x4 patch embedding on the fused image (a 4x2 stereo
micro-cell per view) -> + row embedding a_r -> 7 pre-norm blocks with 2D RoPE on
(row, patch column) -> de-positioned output t - a_r.

Token layout everywhere: (batch, row r, fused column c, channel), c = 2p + q.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import EncoderConfig


def interleave(left: Tensor, right: Tensor) -> Tensor:
    """Fuse a pair: X[..., 2u] = L[..., u], X[..., 2u + 1] = R[..., u]."""
    if left.shape != right.shape:
        raise ValueError(f"left {tuple(left.shape)} and right {tuple(right.shape)} differ")
    b, ch, h, w = left.shape
    return torch.stack((left, right), dim=-1).reshape(b, ch, h, 2 * w)


def rope_positions(rows: Tensor, fused_cols: Tensor) -> tuple[Tensor, Tensor]:
    """RoPE coordinates of each token: (row r, patch column p = c // 2), never c itself."""
    r = rows.reshape(-1, 1).expand(-1, fused_cols.numel())
    p = torch.div(fused_cols, 2, rounding_mode="floor").reshape(1, -1).expand(rows.numel(), -1)
    return r.reshape(-1), p.reshape(-1)


def rope_tables(
    row_pos: Tensor, col_pos: Tensor, head_dim: int, base: float
) -> tuple[Tensor, Tensor]:
    """cos/sin tables (N, head_dim): first half of each head rotates by row, second by column.

    Within each half the rotate-half convention pairs dimension i with i + quarter.
    """
    quarter = head_dim // 4
    steps = torch.arange(quarter, dtype=torch.float32, device=row_pos.device)
    inv_freq = 1.0 / (base ** (steps / quarter))
    ang_r = row_pos.to(torch.float32).unsqueeze(-1) * inv_freq
    ang_c = col_pos.to(torch.float32).unsqueeze(-1) * inv_freq
    angles = torch.cat((ang_r, ang_r, ang_c, ang_c), dim=-1)
    return angles.cos(), angles.sin()


def rotate_halves(x: Tensor) -> Tensor:
    """The rotate-half partner of each dimension, separately in the row and column halves."""
    q = x.shape[-1] // 4
    a, b, c, d = x[..., :q], x[..., q : 2 * q], x[..., 2 * q : 3 * q], x[..., 3 * q :]
    return torch.cat((-b, a, -d, c), dim=-1)


def apply_rope(x: Tensor, cos: Tensor, sin: Tensor) -> Tensor:
    return x * cos + rotate_halves(x) * sin


class Attention(nn.Module):
    """Multi-head self-attention with 2D RoPE on queries and keys."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        self.heads = cfg.heads
        self.head_dim = cfg.head_dim
        self.qkv = nn.Linear(cfg.dim, 3 * cfg.dim)
        self.proj = nn.Linear(cfg.dim, cfg.dim)

    def forward(self, x: Tensor, cos: Tensor, sin: Tensor, mask: Tensor | None = None) -> Tensor:
        b, n, d = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.heads, self.head_dim).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]
        q = apply_rope(q, cos, sin)
        k = apply_rope(k, cos, sin)
        # Fused kernel: softmax(q k^T / sqrt(head_dim)) v, ~4x faster on CPU than the explicit form.
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.proj(out.transpose(1, 2).reshape(b, n, d))


class Block(nn.Module):
    """Pre-norm transformer block: x + attn(ln(x)), then x + mlp(ln(x))."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(cfg.dim, eps=cfg.ln_eps)
        self.attn = Attention(cfg)
        self.norm2 = nn.LayerNorm(cfg.dim, eps=cfg.ln_eps)
        self.fc1 = nn.Linear(cfg.dim, cfg.mlp_hidden)
        self.fc2 = nn.Linear(cfg.mlp_hidden, cfg.dim)

    def forward(self, x: Tensor, cos: Tensor, sin: Tensor, mask: Tensor | None = None) -> Tensor:
        x = x + self.attn(self.norm1(x), cos, sin, mask)
        return x + self.fc2(F.gelu(self.fc1(self.norm2(x))))


class BinoEncoder(nn.Module):
    """Binocular ViT encoder: (left, right) -> de-positioned fused token grid."""

    def __init__(self, cfg: EncoderConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.patch_embed = nn.Conv2d(
            cfg.in_chans,
            cfg.dim,
            kernel_size=(cfg.patch_h, cfg.patch_w),
            stride=(cfg.patch_h, cfg.patch_w),
        )
        self.row_embed = nn.Parameter(torch.zeros(cfg.token_rows, cfg.dim))
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.depth))
        self._init_weights()

    def _init_weights(self) -> None:
        nn.init.trunc_normal_(self.row_embed, std=0.02)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                nn.init.zeros_(m.bias)
            elif isinstance(m, nn.LayerNorm):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def check_input(self, left: Tensor, right: Tensor) -> None:
        cfg = self.cfg
        if left.shape != right.shape:
            raise ValueError(f"left {tuple(left.shape)} and right {tuple(right.shape)} differ")
        _, ch, h, w = left.shape
        if ch != cfg.in_chans:
            raise ValueError(f"expected {cfg.in_chans} channels, got {ch}")
        if h % cfg.patch_h or h > cfg.band_rows:
            raise ValueError(
                f"height {h} must be a multiple of {cfg.patch_h} and <= {cfg.band_rows}"
            )
        if w % cfg.view_cell_w:
            raise ValueError(f"width {w} must be a multiple of {cfg.view_cell_w}")

    def forward_stages(self, left: Tensor, right: Tensor) -> list[Tensor]:
        """Every stage as (B, rows, fused cols, d): [embed, block0, ..., blockN-1, tokens]."""
        self.check_input(left, right)
        x = self.patch_embed(interleave(left, right))  # (B, d, Hp, 2Wp)
        b, d, hp, wf = x.shape
        row_embed = self.row_embed[:hp].reshape(1, hp, 1, d)
        x = x.permute(0, 2, 3, 1) + row_embed
        r, p = rope_positions(torch.arange(hp, device=x.device), torch.arange(wf, device=x.device))
        cos, sin = rope_tables(r, p, self.cfg.head_dim, self.cfg.rope_base)
        stages = [x]
        h = x.reshape(b, hp * wf, d)
        mask = row_window_mask(hp, wf, self.cfg.attention_rows, x.device)
        for block in self.blocks:
            h = block(h, cos, sin, mask)
            stages.append(h.reshape(b, hp, wf, d))
        stages.append(stages[-1] - row_embed)
        return stages

    def forward(self, left: Tensor, right: Tensor) -> Tensor:
        """De-positioned fused token grid (B, H/4, W/2, d)."""
        return self.forward_stages(left, right)[-1]

    def descriptors(self, image: Tensor) -> Tensor:
        """Per-view descriptor map D(I) (B, H/4, W/4, d): run on (I, I), average the phases."""
        tokens = self.forward(image, image)
        return phase_average(tokens)

    def phase_maps(self, left: Tensor, right: Tensor) -> tuple[Tensor, Tensor]:
        """The native pathway: one pass on the actual pair, de-interleaved (`phase_maps`)."""
        return phase_maps(self.forward(left, right))


def uniform_row_embedding(encoder: BinoEncoder, index: int) -> None:
    """Give every token row the row embedding of row `index`, in place. With attention held to
    each token row (`attention_rows` 0) a token row then depends on its own pixel rows only, not
    on where its band starts: a frame's overlapping bands compute each token row once."""
    rows = encoder.row_embed.shape[0]
    if not 0 <= index < rows:
        raise ValueError(f"row embedding index {index} is outside 0..{rows - 1}")
    with torch.no_grad():
        encoder.row_embed.copy_(encoder.row_embed[index : index + 1].clone().expand(rows, -1))


def row_window_mask(rows: int, cols: int, reach: int | None, device: torch.device) -> Tensor | None:
    """Which keys each query may read when attention is held to `reach` token rows either side
    (True: allowed); None for attention over the whole band. Tokens are row-major, so each
    query's keys are one contiguous run: the engine needs only a start and a length per row."""
    if reach is None:
        return None
    row = torch.arange(rows, device=device).unsqueeze(1).expand(rows, cols).reshape(-1)
    return (row[:, None] - row[None, :]).abs() <= reach


def phase_average(tokens: Tensor) -> Tensor:
    """Average the two phase tokens (c = 2p, 2p + 1) of each patch column."""
    return 0.5 * (tokens[:, :, 0::2] + tokens[:, :, 1::2])


def phase_maps(tokens: Tensor) -> tuple[Tensor, Tensor]:
    """The fused grid's two phase maps (B, H/4, W/4, d): even fused columns c = 2p, odd 2p + 1.

    Each fused token covers 4 rows x 2 columns of both views, so both maps hold left and right
    content (different half-columns of a patch column), not one view each."""
    return tokens[:, :, 0::2], tokens[:, :, 1::2]


def encoder_macs(cfg: EncoderConfig, height: int = 48, width: int = 160) -> int:
    """Multiply-accumulates of one encoder pass on a height x width pair: the patch embedding,
    and per block the qkv, attention scores, attention-weighted values, output projection and
    the MLP (norms, softmax, GELU and RoPE are elementwise, not counted). With
    `cfg.attention_rows`, each query reads only the keys of the token rows within reach."""
    rows, cols = height // cfg.patch_h, 2 * width // cfg.patch_w
    tokens = rows * cols
    d = cfg.dim
    embed = tokens * cfg.in_chans * cfg.patch_h * cfg.patch_w * d
    reach = rows if cfg.attention_rows is None else cfg.attention_rows
    pairs = sum(
        cols * cols * (min(r + reach, rows - 1) - max(r - reach, 0) + 1) for r in range(rows)
    )
    attention = tokens * 3 * d * d + 2 * pairs * d + tokens * d * d
    mlp = 2 * tokens * d * cfg.mlp_hidden
    return embed + cfg.depth * (attention + mlp)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


STAGE_NAMES_SUFFIX = "tokens"


def stage_names(cfg: EncoderConfig) -> list[str]:
    """Names of the tensors `forward_stages` returns, as the ONNX export names its outputs."""
    return ["embed"] + [f"block{i}" for i in range(cfg.depth)] + [STAGE_NAMES_SUFFIX]
