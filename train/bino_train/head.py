"""The shared stereo head (DESIGN.md, Readouts): frozen descriptor maps -> token-grid disparity.

    python -m bino_train.head                                         # parameter count
    python -m bino_train.head --checkpoint runs/NAME/last.pt --out weights/bino_head.onnx

Data flow, all on the token grid (T = H/4 rows, P = W/4 patch columns):
  D_L, D_R (B, T, P, 128) -> the same LayerNorm + Linear 128 -> C on both views
  -> groupwise correlation corr[g, k, r, p] = mean over the C/G channels of group g of
     f_L[r, p] * f_R[r, p - k], k = 0 .. D-1 (zero where p - k < 0)
  -> 3D regularisation over (disparity, row, column): Conv3d 3x3x3, ReLU, residual middle layers
  -> logits (B, D, T, P), candidates with p - k < 0 pushed to -1e4
  -> softmax over k: soft-argmin disparity sum_k k * prob_k (patch columns, 4 px each at the
     encoder's input) and confidence max_k prob_k.

Everything is convolutional in (row, column), so any T x P grid works: 48-row training crops,
and full eval images described band by band. The correlation is built from one zero block and
a constant-bound slice per candidate, so the ONNX graph holds only LayerNormalization, MatMul,
Add, Sub, Mul, Concat, Slice, Unsqueeze, Squeeze, Transpose, Conv (3D), Relu, Softmax,
ReduceSum and ReduceMax, and no shape arithmetic (all of them are tract-onnx 0.23 ops).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .export import stamp_metadata
from .model import parameter_count

OPSET = 17
MASKED_LOGIT = 1e4
"""Subtracted from the logits of candidates outside the right image (finite, so int8-friendly)."""


@dataclass(frozen=True)
class HeadConfig:
    desc_dim: int = 128
    proj_dim: int = 96
    groups: int = 16
    hidden: int = 24
    middle_layers: int = 4
    max_disp: int = 12
    """D: candidates 0 .. D-1 patch columns; D = 12 reaches 44 px at w160: above SGBM's 32 px
    search range and the eval split's largest ground truth at w160 (27.7 px, 7 columns),
    with room for the wider (up to 320 px) training crops."""
    ln_eps: float = 1e-5

    def __post_init__(self) -> None:
        if self.proj_dim % self.groups:
            raise ValueError(f"proj_dim {self.proj_dim} not divisible by groups {self.groups}")
        if self.max_disp < 2:
            raise ValueError("max_disp must be at least 2")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


PAPER_HEAD = HeadConfig()
PAPER_HEAD_PARAMETERS = 86_000
"""The paper's figure for the shared head (0.086M); the default config is within 0.1% of it."""


class HeadOutput(NamedTuple):
    logits: Tensor
    """(B, D, T, P), masked candidates at about -1e4."""
    disparity: Tensor
    """(B, T, P) soft-argmin disparity in patch columns."""
    confidence: Tensor
    """(B, T, P) the largest candidate probability."""


def shifted_views(x: Tensor, count: int) -> list[Tensor]:
    """(B, T, P, C) -> [y_0 .. y_{count-1}], y_k[:, :, p] = x[:, :, p - k], zero where p < k.

    One zero block of count - 1 columns on the left, then a static slice per k: in ONNX only
    Mul, Concat and Slice with constant bounds (no Pad with computed pads, no Shape), and the
    width is kept for any P, also P < count.
    """
    zero = x[:, :, :1] * 0.0
    padded = torch.cat([zero] * (count - 1) + [x], dim=2)
    first = count - 1
    return [padded[:, :, first - k : -k] if k else padded[:, :, first:] for k in range(count)]


class StereoHead(nn.Module):
    def __init__(self, cfg: HeadConfig = PAPER_HEAD) -> None:
        super().__init__()
        self.cfg = cfg
        self.norm = nn.LayerNorm(cfg.desc_dim, eps=cfg.ln_eps)
        self.proj = nn.Linear(cfg.desc_dim, cfg.proj_dim)
        per_group = cfg.proj_dim // cfg.groups
        # Channel -> group averaging as one MatMul: no reshape with dynamic sizes in the graph.
        group_of = torch.arange(cfg.proj_dim) // per_group
        pool = (group_of[:, None] == torch.arange(cfg.groups)[None, :]).float() / per_group
        self.group_pool: Tensor
        self.candidates: Tensor
        self.register_buffer("group_pool", pool, persistent=False)
        self.register_buffer(
            "candidates", torch.arange(cfg.max_disp, dtype=torch.float32), persistent=False
        )
        self.stem = nn.Conv3d(cfg.groups, cfg.hidden, 3, padding=1)
        self.middle = nn.ModuleList(
            nn.Conv3d(cfg.hidden, cfg.hidden, 3, padding=1) for _ in range(cfg.middle_layers)
        )
        self.out = nn.Conv3d(cfg.hidden, 1, 3, padding=1)

    @torch.no_grad()
    def init_projection(self, desc: Tensor) -> None:
        """Data-dependent init: the projection becomes centred PCA of LayerNorm(desc).

        Encoder descriptors share a large common vector (about 5-8x the token-to-token
        spread): with a random projection the correlation is mostly that constant and the
        head needs many steps to learn to remove it. Centring, then keeping the top C
        principal directions (scaled to unit mean variance), starts the correlation as an
        inner product of what differs between tokens, which is what matching needs.
        """
        x = self.norm(desc.reshape(-1, self.cfg.desc_dim).float())
        mean = x.mean(dim=0)
        cov = torch.cov((x - mean).T)
        eigval, eigvec = torch.linalg.eigh(cov)  # ascending
        top = eigvec[:, -self.cfg.proj_dim :].flip(-1).T  # (C, desc_dim)
        scale = eigval[-self.cfg.proj_dim :].clamp_min(0).mean().sqrt().clamp_min(1e-6)
        weight = top / scale
        self.proj.weight.copy_(weight)
        self.proj.bias.copy_(-(weight @ mean))

    def project(self, desc: Tensor) -> Tensor:
        """(B, T, P, desc_dim) -> (B, T, P, C); the same weights for both views."""
        return self.proj(self.norm(desc))

    def correlation(self, feat_left: Tensor, feat_right: Tensor) -> Tensor:
        """(B, G, D, T, P): group means of f_L[p] * f_R[p - k]; zero where p - k < 0."""
        slices = [
            torch.matmul(feat_left * shifted, self.group_pool)
            for shifted in shifted_views(feat_right, self.cfg.max_disp)
        ]
        return torch.stack(slices, dim=1).permute(0, 4, 1, 2, 3)

    def candidate_mask(self, desc: Tensor) -> Tensor:
        """(B, D, T, P): 1 where the candidate p - k lies inside the right view, else 0."""
        ones = desc[..., :1] * 0.0 + 1.0  # not ones_like: keeps Shape ops out of the graph
        return torch.cat(shifted_views(ones, self.cfg.max_disp), dim=-1).permute(0, 3, 1, 2)

    def regularise(self, volume: Tensor) -> Tensor:
        """(B, G, D, T, P) -> (B, D, T, P) logits before masking."""
        x = F.relu(self.stem(volume))
        for conv in self.middle:
            x = x + F.relu(conv(x))  # residual: a deep stack of tiny convs still trains quickly
        return self.out(x).squeeze(1)

    def forward(self, desc_left: Tensor, desc_right: Tensor) -> HeadOutput:
        if not torch.onnx.is_in_onnx_export() and desc_left.shape != desc_right.shape:
            raise ValueError(f"{tuple(desc_left.shape)} vs {tuple(desc_right.shape)}")
        volume = self.correlation(self.project(desc_left), self.project(desc_right))
        valid = self.candidate_mask(desc_left)
        logits = self.regularise(volume) - (1.0 - valid) * MASKED_LOGIT
        prob = torch.softmax(logits, dim=1)
        disparity = (prob * self.candidates.view(1, -1, 1, 1)).sum(dim=1)
        confidence = prob.amax(dim=1)
        return HeadOutput(logits, disparity, confidence)


@dataclass(frozen=True)
class LossParts:
    loss: Tensor
    smooth_l1: float
    ce: float
    epe_cols: float
    """Mean |soft disparity - target| over the supervised cells, in patch columns."""
    cells: int


def supervised_cells(target: Tensor, max_disp: int) -> Tensor:
    """Cells with a usable target: finite, in [0, D-1], and the rounded target a valid candidate
    (p - round(target) >= 0: columns near the left edge cannot see large disparities)."""
    cols = torch.arange(target.shape[-1], device=target.device).view(1, 1, -1)
    finite = torch.isfinite(target)
    safe = torch.where(finite, target, torch.zeros_like(target))
    return finite & (safe >= 0) & (safe <= max_disp - 1) & (torch.round(safe) <= cols)


def head_loss(
    out: HeadOutput, target: Tensor, ce_weight: float = 1.0, weight: Tensor | None = None
) -> LossParts:
    """Smooth L1 on the soft disparity + cross-entropy on the rounded target, supervised cells
    only, each cell weighted by `weight` (B, T, P) (None: 1). target: (B, T, P) patch columns,
    NaN where unknown."""
    d = out.logits.shape[1]
    mask = supervised_cells(target, d)
    if weight is not None:
        mask = mask & (weight > 0)
    n = int(mask.sum())
    if n == 0:
        zero = out.disparity.sum() * 0.0  # keeps the graph: backward() still works
        return LossParts(zero, 0.0, 0.0, 0.0, 0)
    tgt = target[mask]
    w = weight[mask] if weight is not None else torch.ones_like(tgt)
    w = w / w.sum()
    pred = out.disparity[mask]
    sl1 = (F.smooth_l1_loss(pred, tgt, beta=1.0, reduction="none") * w).sum()
    logits = out.logits.permute(0, 2, 3, 1)[mask]  # (n, D)
    ce = (F.cross_entropy(logits, torch.round(tgt).long(), reduction="none") * w).sum()
    loss = sl1 + ce_weight * ce
    epe = float((pred.detach() - tgt).abs().mean())
    return LossParts(loss, float(sl1.detach()), float(ce.detach()), epe, n)


def head_parameters(cfg: HeadConfig = PAPER_HEAD) -> int:
    return parameter_count(StereoHead(cfg))


def load_head(checkpoint: Path) -> StereoHead:
    """A head from a head-training checkpoint (`head_config` + `head` state dict)."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    head = StereoHead(HeadConfig(**state["head_config"]))
    head.load_state_dict(state["head"])
    return head.eval()


class _ExportWrapper(nn.Module):
    def __init__(self, head: StereoHead, logits: bool) -> None:
        super().__init__()
        self.head = head
        self.logits = logits

    def forward(self, desc_left: Tensor, desc_right: Tensor) -> tuple[Tensor, ...]:
        out = self.head(desc_left, desc_right)
        if self.logits:
            return out.disparity, out.confidence, out.logits
        return out.disparity, out.confidence


def head_output_names(logits: bool) -> list[str]:
    return ["disparity", "confidence", "logits"] if logits else ["disparity", "confidence"]


def export_head_onnx(
    head: StereoHead,
    out: Path,
    *,
    provenance: str,
    logits: bool = False,
    rows: int = 12,
    cols: int = 40,
) -> None:
    """Inputs `desc_left`, `desc_right` (1, T, P, desc_dim), T and P dynamic; outputs
    `disparity` and `confidence` (1, T, P) (patch columns), optionally `logits` (1, D, T, P)."""
    cfg = head.cfg
    example = torch.zeros(1, rows, cols, cfg.desc_dim)
    names = head_output_names(logits)
    grid = {1: "token_rows", 2: "patch_cols"}
    dynamic: dict[str, dict[int, str]] = {"desc_left": grid, "desc_right": grid}
    for name in names:
        dynamic[name] = {2: "token_rows", 3: "patch_cols"} if name == "logits" else grid
    out.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        torch.onnx.export(
            _ExportWrapper(head.eval(), logits),
            (example, example),
            str(out),
            input_names=["desc_left", "desc_right"],
            output_names=names,
            dynamic_axes=dynamic,
            opset_version=OPSET,
            dynamo=False,
        )
    meta = {
        "bino.weights": provenance,
        "bino.head_config": repr(cfg.to_dict()),
        "bino.parameters": str(parameter_count(head)),
        "bino.disparity_unit": "patch columns (4 px at the encoder input)",
    }
    stamp_metadata(out, meta)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, help="head checkpoint (head_train last.pt)")
    parser.add_argument("--out", type=Path, help="ONNX file to write")
    parser.add_argument("--logits", action="store_true", help="also output the logits")
    parser.add_argument(
        "--state-dict", type=Path, help="also save {head_config, head} (PyTorch) to this file"
    )
    args = parser.parse_args(argv)
    if args.checkpoint is None:
        n = head_parameters()
        print(f"stereo head: {n:,} parameters ({n / 1e6:.4f}M), config {PAPER_HEAD.to_dict()}")
        return
    if args.out is None:
        parser.error("--out is required with --checkpoint")
    if not args.checkpoint.is_file():
        sys.exit(f"error: checkpoint {args.checkpoint} does not exist")
    state = torch.load(args.checkpoint, map_location="cpu", weights_only=False)
    if state.get("encoder_source", {}).get("kind") == "random-init" and (
        "weights" in args.out.resolve().parts
    ):
        sys.exit(f"error: refusing to write a head trained on a random-init encoder ({args.out})")
    head = load_head(args.checkpoint)
    provenance = f"head checkpoint {args.checkpoint.name} at step {state.get('step')}"
    export_head_onnx(head, args.out, provenance=provenance, logits=args.logits)
    print(f"wrote {args.out} ({parameter_count(head):,} parameters; {provenance})")
    if args.state_dict is not None:
        torch.save({"head_config": head.cfg.to_dict(), "head": head.state_dict()}, args.state_dict)
        print(f"wrote {args.state_dict}")


if __name__ == "__main__":
    main()
