"""The census residual net (census_residual.py) and its int8 fake-quantised twin.

A small fully convolutional net in the manner of StereoNet / ActiveStereoNet's refinement: a
3x3 stem, residual blocks of two dilated 3x3 convolutions (dilations `DILATIONS`, so the
receptive field spans about 70 px: enough to carry a surface's disparity across a textureless
patch or an occlusion), ReLU, and a 3x3 output convolution to one channel, the residual in px.
The output convolution starts at zero, so the untrained net returns its anchor exactly
(census+lr+ref with the default anchor).

`QuantisedNet` runs the same weights as an integer engine would: weights int8 per output channel
(symmetric), every convolution's input in Q8 (8-bit, scale from calibration batches: the input
features per channel, hidden activations per tensor, unsigned after a ReLU), biases kept in
float (an int32 accumulator's), the residual output rounded to 1/16 px.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

DILATIONS = (1, 2, 4, 8, 1)
CHANNELS = 16
OUTPUT_STEP = 1.0 / 16.0
"""The integer twin's residual resolution (px)."""


class ResidualBlock(nn.Module):
    def __init__(self, channels: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation)

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(x + self.conv2(F.relu(self.conv1(x))))


class ResidualNet(nn.Module):
    """(B, C, H, W) features -> (B, H, W) residual (px)."""

    def __init__(self, in_channels: int, channels: int = CHANNELS) -> None:
        super().__init__()
        self.stem = nn.Conv2d(in_channels, channels, 3, padding=1)
        self.blocks = nn.ModuleList(ResidualBlock(channels, d) for d in DILATIONS)
        self.out = nn.Conv2d(channels, 1, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        assert self.out.bias is not None
        nn.init.zeros_(self.out.bias)

    def forward(self, x: Tensor) -> Tensor:
        h = F.relu(self.stem(x))
        for block in self.blocks:
            h = block(h)
        return self.out(h)[:, 0]

    def convolutions(self) -> list[nn.Conv2d]:
        """Every convolution, in the order the forward pass runs them."""
        convs = [self.stem]
        for block in self.blocks:
            assert isinstance(block, ResidualBlock)
            convs += [block.conv1, block.conv2]
        return [*convs, self.out]


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


def quantise_weight(weight: Tensor) -> Tensor:
    """Symmetric int8 per output channel, returned dequantised."""
    scale = weight.abs().amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-12) / 127.0
    return torch.round(weight / scale).clamp(-127, 127) * scale


def quantise_activation(x: Tensor, scale: Tensor, signed: bool) -> Tensor:
    """Q8 (int8 if `signed`, else uint8) at `scale` per tensor or per channel, dequantised."""
    lo, hi = (-127.0, 127.0) if signed else (0.0, 255.0)
    return torch.round(x / scale).clamp(lo, hi) * scale


class QuantisedNet(nn.Module):
    """`ResidualNet`'s forward pass with int8 weights and Q8 inputs to every convolution."""

    def __init__(self, net: ResidualNet, calibration: Iterable[Tensor]) -> None:
        super().__init__()
        self.net = net
        self.convs = net.convolutions()
        self.weights = [quantise_weight(c.weight.detach()) for c in self.convs]
        self.scales = self._calibrate(calibration)

    @torch.no_grad()
    def _calibrate(self, batches: Iterable[Tensor]) -> list[Tensor]:
        """Each convolution input's scale: its largest magnitude seen (per channel for the
        features, which are signed int8; per tensor for the ReLU outputs, uint8)."""
        peaks: list[Tensor] | None = None
        for x in batches:
            seen = [
                t.abs().amax(dim=(0, 2, 3)).view(1, -1, 1, 1) if i == 0 else t.abs().amax()
                for i, t in enumerate(self._inputs(x))
            ]
            peaks = (
                seen
                if peaks is None
                else [torch.maximum(a, b) for a, b in zip(peaks, seen, strict=True)]
            )
        if peaks is None:
            raise ValueError("no calibration batches")
        return [p.clamp_min(1e-6) / (127.0 if i == 0 else 255.0) for i, p in enumerate(peaks)]

    def _inputs(self, x: Tensor) -> list[Tensor]:
        """The float net's input to each convolution."""
        seen: list[Tensor] = []

        def hook(_: nn.Module, args: tuple[Tensor, ...]) -> None:
            seen.append(args[0])

        handles = [c.register_forward_pre_hook(hook) for c in self.convs]
        try:
            self.net(x)
        finally:
            for h in handles:
                h.remove()
        return seen

    @torch.no_grad()
    def forward(self, x: Tensor) -> Tensor:
        it = iter(range(len(self.convs)))

        def conv(i: int, t: Tensor) -> Tensor:
            c = self.convs[i]
            q = quantise_activation(t, self.scales[i], signed=i == 0)
            return F.conv2d(q, self.weights[i], c.bias, padding=c.padding, dilation=c.dilation)

        h = F.relu(conv(next(it), x))
        for _ in self.net.blocks:
            a = F.relu(conv(next(it), h))
            h = F.relu(h + conv(next(it), a))
        out = conv(next(it), h)[:, 0]
        return torch.round(out / OUTPUT_STEP) * OUTPUT_STEP
