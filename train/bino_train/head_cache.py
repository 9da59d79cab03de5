"""A descriptor cache for head training: crops encoded once, reused by every head step.

    python -m bino_train.head_cache --encoder runs/PRE/last.pt --out runs/cache_NAME.pt \
        --count 6000 [--label-weighting lr] [--synthetic-fraction 0.5] [--pathway native] \
        [--max-disp 16] [--labeled-fraction 0.35 --synthetic-kind layered --blur-prob 0.2]

Sample i is `HeadSampler(data, seed).sample(i)` (synthetic scenes and SGBM pseudo-labels of
the head-training pairs: the train split less the validation pairs), encoded by the frozen
encoder under no_grad (`--pathway export`: D(L) and D(R), two passes a crop; `native`: the
phase maps of one pass on (L, R), head_data.encode_maps); the file holds every DescBatch field
at storage precision (maps and clean crops fp16) plus what made it (data config, seed, count,
encoder hash, pathway), so a head run that reads it can check it is paired with the right
encoder and pathway and resume exactly.
About 0.18 s a sample on one core of the 2-core dev VM (two 48x160 encoder passes + SGBM);
the native pathway about 0.3 s on the same VM while it was shared by several jobs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from .head_data import (
    HEAD_AUGMENT,
    LABEL_WEIGHTINGS,
    PATHWAYS,
    SYNTHETIC_KINDS,
    DataConfig,
    DescBatch,
    HeadSampler,
    batch_fields,
    check_pathway,
    encode,
    stored_batch,
)
from .model import BinoEncoder

CHUNK = 64


@dataclass(frozen=True)
class DescriptorCache:
    meta: dict[str, Any]
    data: DescBatch

    @property
    def count(self) -> int:
        return int(self.data.left.shape[0])

    @property
    def pathway(self) -> str:
        return cache_pathway(self.meta)


def cache_pathway(meta: dict[str, Any]) -> str:
    """The pathway a cache was encoded for (caches from before the native pathway: export)."""
    return check_pathway(str(meta.get("pathway", "export")))


def build_cache(
    encoder: BinoEncoder,
    encoder_sha256: str,
    data: DataConfig,
    seed: int,
    count: int,
    data_dir: Path | None,
    progress: bool = True,
    pathway: str = "export",
) -> DescriptorCache:
    sampler = HeadSampler(data, seed, data_dir)
    device = torch.device("cpu")
    encoder = encoder.eval()
    chunks: list[DescBatch] = []
    start = time.perf_counter()
    for lo in range(0, count, CHUNK):
        hi = min(count, lo + CHUNK)
        chunks.append(
            stored_batch(encode(encoder, sampler.samples(range(lo, hi)), device, pathway))
        )
        if progress:
            rate = hi / (time.perf_counter() - start)
            eta = (count - hi) / rate
            print(f"cache: {hi}/{count} samples, {rate:.1f}/s, {eta / 60:.1f} min left", flush=True)
    fields = [torch.cat(ts) for ts in zip(*(batch_fields(c) for c in chunks), strict=True)]
    meta = {
        "data": data.to_dict(),
        "seed": seed,
        "count": count,
        "encoder_sha256": encoder_sha256,
        "pathway": check_pathway(pathway),
        "build_seconds": round(time.perf_counter() - start, 1),
    }
    return DescriptorCache(meta, DescBatch(*fields))


def meta_path(path: Path) -> Path:
    return path.with_name(path.name + ".json")


def save_cache(cache: DescriptorCache, path: Path) -> None:
    """The cache file and, beside it, its meta as JSON (readable without loading the data)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    torch.save({"meta": cache.meta, "fields": batch_fields(cache.data)}, partial)
    partial.replace(path)
    meta_path(path).write_text(json.dumps(cache.meta, indent=1) + "\n")


def load_cache_meta(path: Path) -> dict[str, Any]:
    if not meta_path(path).is_file():
        raise FileNotFoundError(f"descriptor cache {path} has no {meta_path(path).name}")
    meta: dict[str, Any] = json.loads(meta_path(path).read_text())
    return meta


def load_cache(path: Path) -> DescriptorCache:
    if not path.is_file():
        raise FileNotFoundError(f"descriptor cache {path} does not exist")
    state = torch.load(path, map_location="cpu", weights_only=False)
    return DescriptorCache(state["meta"], DescBatch(*state["fields"]))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--encoder", type=Path, required=True, help="encoder checkpoint")
    p.add_argument("--out", type=Path, required=True, help="cache file to write")
    p.add_argument("--count", type=int, default=6000, help="samples")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--synthetic-fraction", type=float, default=0.5)
    p.add_argument("--label-weighting", choices=LABEL_WEIGHTINGS, default="lr")
    p.add_argument("--pathway", choices=PATHWAYS, default="export", help="maps to store")
    p.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument(
        "--max-disp",
        type=int,
        default=DataConfig().max_disp,
        help="disparity candidates in patch columns (labels and synthetic scenes up to "
        "4 x (max_disp - 1) px; train the head with the same --max-disp)",
    )
    p.add_argument(
        "--labeled-fraction",
        type=float,
        default=0.0,
        help="share of crops from the labeled train pairs' ground truth (labeled.py)",
    )
    p.add_argument(
        "--synthetic-kind",
        choices=SYNTHETIC_KINDS,
        default="plane",
        help="synthetic scenes: plane (head_data) or layered (synth_train)",
    )
    p.add_argument(
        "--blur-prob", type=float, default=0.0, help="share of crops with one view defocused"
    )
    p.add_argument("--widths", type=int, nargs=2, metavar=("MIN", "MAX"), help="resize widths")
    args = p.parse_args(argv)
    if not 2 <= args.max_disp <= 64:
        sys.exit(f"error: --max-disp {args.max_disp} is outside 2..64")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if not args.encoder.is_file():
        sys.exit(f"error: encoder checkpoint {args.encoder} does not exist")
    from .export import load_encoder
    from .head_train import encoder_digest

    encoder = load_encoder(args.encoder)
    data = replace(
        DataConfig(),
        synthetic_fraction=args.synthetic_fraction,
        label_weighting=args.label_weighting,
        max_disp=args.max_disp,
        labeled_fraction=args.labeled_fraction,
        synthetic_kind=args.synthetic_kind,
        augment=replace(HEAD_AUGMENT, blur_prob=args.blur_prob),
    )
    if args.widths is not None:
        data = replace(data, min_width=args.widths[0], max_width=args.widths[1])
    digest = encoder_digest(encoder)
    cache = build_cache(
        encoder, digest, data, args.seed, args.count, args.data, pathway=args.pathway
    )
    cache.meta["encoder_path"] = str(args.encoder.resolve())
    save_cache(cache, args.out)
    print(
        f"wrote {args.out}: {cache.count} {args.pathway} samples in {cache.meta['build_seconds']} s"
    )


if __name__ == "__main__":
    main()
