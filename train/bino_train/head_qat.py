"""Quantisation-aware training of the shared head: its forward with the int8 engine's roundings.

The int8 head (docs/int8-model.md, "Quantisation") rounds at five places the float head does not:
the LayerNorm's z-scores and the projection's output (per tensor, symmetric, MSE-chosen clip),
the correlation volume (per tensor, symmetric, a percentile bound), each convolution's output
after ReLU and its residual carry (per tensor, 0 .. 99.99th percentile), and every weight (per
output channel, symmetric, max-abs; the LayerNorm's affine folded into the projection). A head
trained through those roundings, with straight-through gradients (`fake_quant`), learns weights
whose int8 readout loses less to the float one; `bino quantize` still chooses the blob's own
formats afterwards. The ranges are calibrated once, on the head the run starts from
(`calibrate`), and kept in the run's checkpoint, so a resumed run rounds as it did.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from .head import MASKED_LOGIT, HeadOutput, StereoHead

LEVELS = 127
"""Symmetric int8 codes: [-127, 127], as the engine's weights and activations."""


def fake_quant(x: Tensor, scale: float, lo: int = -LEVELS, hi: int = LEVELS) -> Tensor:
    """x rounded to `scale * q`, q in [lo, hi]; the gradient passes straight through."""
    q = torch.clamp(torch.round(x / scale), lo, hi) * scale
    return x + (q - x).detach()


def fake_quant_unsigned(x: Tensor, top: float) -> Tensor:
    """A non-negative tensor on 256 codes from 0 to `top` (the engine's asymmetric format)."""
    return fake_quant(x, max(top, 1e-8) / 255.0, 0, 255)


def fake_quant_weight(w: Tensor) -> Tensor:
    """Per output channel (dim 0), symmetric, scale max|w| / 127."""
    flat = w.reshape(w.shape[0], -1)
    scale = flat.abs().amax(dim=1).clamp_min(1e-8) / LEVELS
    shape = (-1,) + (1,) * (w.dim() - 1)
    q = torch.clamp(torch.round(w / scale.view(shape)), -LEVELS, LEVELS) * scale.view(shape)
    return w + (q - w).detach()


def mse_clip(x: Tensor) -> float:
    """The symmetric clip of x's int8 grid with the least squared error (candidates: upper
    percentiles of |x|), as `bino quantize` picks its MSE formats."""
    a = x.detach().abs().flatten().float()
    if a.numel() > 1_000_000:
        a = a[torch.randperm(a.numel(), generator=torch.Generator().manual_seed(0))[:1_000_000]]
    best, best_err = float(a.max()), float("inf")
    for p in (0.99, 0.995, 0.999, 0.9995, 0.9999, 1.0):
        clip = max(float(torch.quantile(a, p)), 1e-8)
        err = float(
            ((fake_quant(x.detach().float(), clip / LEVELS) - x.detach().float()) ** 2).mean()
        )
        if err < best_err:
            best, best_err = clip, err
    return best


def percentile(x: Tensor, p: float) -> float:
    a = x.detach().abs().flatten().float()
    if a.numel() > 1_000_000:
        a = a[torch.randperm(a.numel(), generator=torch.Generator().manual_seed(0))[:1_000_000]]
    return max(float(torch.quantile(a, p)), 1e-8)


@dataclass(frozen=True)
class HeadRanges:
    """The real ranges the fake-quantised forward rounds to."""

    z: float
    """LayerNorm z-scores: symmetric clip."""
    proj: float
    """Projected features: symmetric clip."""
    corr: float
    """Correlation volume: symmetric bound."""
    hidden: tuple[float, ...]
    """Stem output, then each middle layer's carry (x + ReLU(conv x)): top of [0, top]."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> HeadRanges:
        return HeadRanges(d["z"], d["proj"], d["corr"], tuple(d["hidden"]))


def check_head(head: StereoHead) -> None:
    if head.cfg.pathway != "export":
        raise ValueError("quantisation-aware training covers the shared (export) head only")


def normalised(head: StereoHead, desc: Tensor) -> Tensor:
    """LayerNorm without its affine (which the engine folds into the projection)."""
    return F.layer_norm(desc.float(), (head.cfg.desc_dim,), eps=head.cfg.ln_eps)


def folded_projection(head: StereoHead) -> tuple[Tensor, Tensor]:
    """(weight, bias) of the projection with the LayerNorm's affine folded in."""
    w, b = head.proj.weight, head.proj.bias
    return w * head.norm.weight[None, :], b + w @ head.norm.bias


@torch.no_grad()
def calibrate(
    head: StereoHead, left: Tensor, right: Tensor, corr_percentile: float = 0.999
) -> HeadRanges:
    """Ranges from the float head on calibration maps (B, T, P, desc_dim)."""
    check_head(head)
    z = torch.cat([normalised(head, left), normalised(head, right)])
    feat_l, feat_r = head.features(left.float(), right.float())
    volume = head.correlation(feat_l, feat_r)
    hidden = []
    x = F.relu(head.stem(volume))
    hidden.append(percentile(x, 0.9999))
    for conv in head.middle:
        x = x + F.relu(conv(x))
        hidden.append(percentile(x, 0.9999))
    return HeadRanges(
        z=mse_clip(z),
        proj=mse_clip(torch.cat([feat_l, feat_r])),
        corr=percentile(volume, corr_percentile),
        hidden=tuple(hidden),
    )


def conv_q(conv: torch.nn.Module, x: Tensor) -> Tensor:
    """A 3x3x3 convolution of the head with its weights on their int8 grid."""
    if not isinstance(conv, torch.nn.Conv3d):
        raise TypeError(f"expected a Conv3d, got {type(conv).__name__}")
    return F.conv3d(x, fake_quant_weight(conv.weight), conv.bias, padding=1)


def qat_forward(
    head: StereoHead, ranges: HeadRanges, desc_left: Tensor, desc_right: Tensor
) -> HeadOutput:
    """StereoHead.forward with the int8 engine's roundings (module doc)."""
    check_head(head)
    weight, bias = folded_projection(head)
    weight = fake_quant_weight(weight)

    def project(desc: Tensor) -> Tensor:
        z = fake_quant(normalised(head, desc), ranges.z / LEVELS)
        return fake_quant(F.linear(z, weight, bias), ranges.proj / LEVELS)

    volume = head.correlation(project(desc_left), project(desc_right))
    volume = fake_quant(volume, ranges.corr / LEVELS)
    x = fake_quant_unsigned(F.relu(conv_q(head.stem, volume)), ranges.hidden[0])
    for conv, top in zip(head.middle, ranges.hidden[1:], strict=True):
        x = fake_quant_unsigned(x + F.relu(conv_q(conv, x)), top)
    valid = head.candidate_mask(desc_left)
    logits = conv_q(head.out, x).squeeze(1) - (1.0 - valid) * MASKED_LOGIT
    prob = torch.softmax(logits, dim=1)
    disparity = (prob * head.candidates.view(1, -1, 1, 1)).sum(dim=1)
    return HeadOutput(logits, disparity, prob.amax(dim=1))
