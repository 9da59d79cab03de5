"""Frozen-encoder descriptors of head training crops (head_data.py's samples).

`encode` runs the frozen encoder under no_grad on a list of samples and returns a `DescBatch`:
the two maps a head reads for each crop (`PATHWAYS`: D(L) and D(R) on the export pathway, the
phase maps of one pass on (L, R) on the native one), with the labels, their weights and the
crops. `DescriptorPool` keeps a ring of encoded samples so one encoder pass serves several head
steps; `stored_batch` / `gather` convert to and from the storage dtypes a pool or a descriptor
cache (head_cache.py) keeps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from .model import BinoEncoder

if TYPE_CHECKING:
    from .head_data import Gray, Sample


@dataclass(frozen=True)
class DescBatch:
    left: Tensor
    """(B, T, P, d) descriptor maps of the left crops (native pathway: the even phase maps)."""
    right: Tensor
    """The right crops' descriptor maps (native pathway: the odd phase maps)."""
    label: Tensor
    """(B, T, P) patch columns, NaN where unknown."""
    synthetic: Tensor
    """(B,) bool."""
    weight: Tensor | None = None
    """(B, T, P) label confidence (None: 1 where labelled)."""
    images: Tensor | None = None
    """(B, 2, H, W) the clean crops (left, right), for photometric terms."""


ENCODE_CHUNK = 32
"""Images per encoder forward; fixed so that a regenerated batch is bit-identical."""


PATHWAYS = ("export", "native")
"""export: D(I) of each view, encoder on (L, L) and (R, R); native: the phase maps of one pass on
(L, R) (DESIGN.md, Readouts)."""


def check_pathway(pathway: str) -> str:
    if pathway not in PATHWAYS:
        raise ValueError(f"pathway {pathway!r} not in {PATHWAYS}")
    return pathway


def gray_batch(images: Sequence[Gray], device: torch.device) -> Tensor:
    """(N, 3, H, W) from grayscale crops (replicated, as the encoder expects)."""
    x = torch.from_numpy(np.stack(images)[:, None]).to(device)
    return x.expand(-1, 3, -1, -1)


def encode_maps(
    encoder: BinoEncoder, samples: Sequence[Sample], device: torch.device, pathway: str
) -> tuple[Tensor, Tensor]:
    """The two maps a head reads for each crop: (D(L), D(R)) on the export pathway, the phase
    maps (even, odd) of the encoder on (L, R) on the native one. Each (N, T, P, d), fp32."""
    if check_pathway(pathway) == "native":
        evens, odds = [], []
        for i in range(0, len(samples), ENCODE_CHUNK):
            chunk = samples[i : i + ENCODE_CHUNK]
            left = gray_batch([s.left for s in chunk], device)
            right = gray_batch([s.right for s in chunk], device)
            even, odd = encoder.phase_maps(left, right)
            evens.append(even.float())
            odds.append(odd.float())
        return torch.cat(evens), torch.cat(odds)
    images = [s.left for s in samples] + [s.right for s in samples]
    descs = [
        encoder.descriptors(gray_batch(images[i : i + ENCODE_CHUNK], device)).float()
        for i in range(0, len(images), ENCODE_CHUNK)
    ]
    d = torch.cat(descs)
    return d[: len(samples)], d[len(samples) :]


@torch.no_grad()
def encode(
    encoder: BinoEncoder,
    samples: Sequence[Sample],
    device: torch.device,
    pathway: str = "export",
) -> DescBatch:
    """The maps of each crop (`encode_maps`) under no_grad (the encoder is frozen), with the
    labels, their weights and the crops themselves."""
    left, right = encode_maps(encoder, samples, device, pathway)
    label = torch.from_numpy(np.stack([s.label for s in samples])).to(device)
    weight = torch.from_numpy(np.stack([s.label_weight() for s in samples])).to(device)
    synthetic = torch.tensor([s.synthetic for s in samples], device=device)
    crops = torch.from_numpy(
        np.stack([np.stack(s.clean or (s.left, s.right)) for s in samples])
    ).to(device)
    return DescBatch(left, right, label, synthetic, weight, crops)


def batch_fields(batch: DescBatch) -> list[Tensor]:
    out = [batch.left, batch.right, batch.label, batch.synthetic, batch.weight, batch.images]
    if any(t is None for t in out):
        raise ValueError("a descriptor batch without weights or images")
    return [t for t in out if t is not None]


STORED_DTYPES = (
    torch.float16,
    torch.float16,
    torch.float32,
    torch.bool,
    torch.float16,
    torch.float16,
)
"""How a pool or cache keeps each field of DescBatch (descriptors and crops at half precision)."""


def stored_batch(batch: DescBatch) -> DescBatch:
    """A batch in the storage dtypes (a cache file holds this)."""
    return DescBatch(*(t.to(d) for t, d in zip(batch_fields(batch), STORED_DTYPES, strict=True)))


def gather(stored: DescBatch, idx: Tensor) -> DescBatch:
    """Rows `idx` of a stored batch, in float32 (bool flags kept)."""
    out = [t[idx] if t.dtype == torch.bool else t[idx].float() for t in batch_fields(stored)]
    return DescBatch(*out)


class DescriptorPool:
    """A ring of encoded samples: each step encodes `refresh` new samples and trains on `batch`
    drawn from the pool, so the frozen encoder's cost is shared by several head steps.

    Step s encodes samples [s * refresh, (s + 1) * refresh) into slot group s mod
    (size / refresh); the pool after step s is a function of s alone and is rebuilt on resume.
    With size == refresh == batch every step trains on fresh samples.
    """

    def __init__(self, size: int, refresh: int) -> None:
        if size < refresh or size % refresh:
            raise ValueError(f"pool size {size} must be a multiple of refresh {refresh}")
        self.size, self.refresh = size, refresh
        self.groups = size // refresh
        self.data: DescBatch | None = None
        self.filled = 0

    def insert(self, step: int, batch: DescBatch) -> None:
        fields = batch_fields(batch)
        if self.data is None:
            self.data = DescBatch(
                *(
                    torch.empty((self.size, *t.shape[1:]), dtype=d, device=t.device)
                    for t, d in zip(fields, STORED_DTYPES, strict=True)
                )
            )
        at = (step % self.groups) * self.refresh
        for dst, src in zip(batch_fields(self.data), fields, strict=True):
            dst[at : at + self.refresh] = src.to(dst.dtype)
        self.filled = min(self.size, max(self.filled, at + self.refresh))

    def draw(self, rng: np.random.Generator, batch: int) -> DescBatch:
        if self.data is None:
            raise RuntimeError("empty pool")
        replace_ = self.filled < batch
        idx = torch.from_numpy(rng.choice(self.filled, size=batch, replace=replace_))
        return gather(self.data, idx.to(self.data.left.device))
