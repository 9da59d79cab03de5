"""A descriptor cache re-encoded by the int8 engine, for quantisation-aware head training.

    python -m bino_train.int8_cache --cache runs/headcache/C.pt --out runs/headcache/C_int8.pt \
        [--blob ../weights/bino_int8.bin] [--bino PATH] [--chunk 250] [--threads 2]

The shipped head reads the int8 engine's descriptors on the board but was trained on the float
encoder's; on natural images that costs it more than its own quantisation does. This rebuilds
every crop of a cache made by head_cache.py (HeadSampler seeds each sample by its index, so
sample i is the same crop; its labels are checked against the cache's), runs the int8 engine on
the crops (`bino describe`, the maps of the cache's pathway, dequantised) and writes a cache
whose maps are the engine's and whose labels, weights and clean crops are the original's. The
meta keeps the encoder's hash (the float head still pairs with it) and adds the blob's.
Chunks are kept beside the output (`OUT.parts/`), so an interrupted run resumes.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from .head_cache import DescriptorCache, load_cache, save_cache
from .head_data import DataConfig, HeadSampler, Sample

REPO = Path(__file__).resolve().parents[2]


def default_bino() -> Path:
    """The release `bino` of this checkout (CARGO_TARGET_DIR as scripts/env.sh sets it)."""
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    return target / "release" / "bino"


def crop_stack(samples: list[Sample]) -> np.ndarray:
    """(N, 2, H, W) float32: each sample's encoder input (the views after the nuisances)."""
    return np.stack([np.stack([s.left, s.right]) for s in samples]).astype(np.float32)


def same_labels(samples: list[Sample], labels: torch.Tensor) -> bool:
    """Whether the regenerated samples carry the cache's labels (NaN where unknown)."""
    fresh = torch.from_numpy(np.stack([s.label for s in samples])).float()
    return bool(torch.equal(fresh.isnan(), labels.isnan())) and bool(
        torch.equal(fresh.nan_to_num(), labels.float().nan_to_num())
    )


def describe(bino: Path, blob: Path, pathway: str, crops: np.ndarray, threads: int) -> np.ndarray:
    """The engine's maps of `crops`: (N, 2, H/4, W/4, DIM) float32."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "crops.npy", Path(tmp) / "maps.npy"
        np.save(src, crops)
        cmd = [str(bino), "describe", "--crops", str(src), "--blob", str(blob)]
        cmd += ["--pathway", pathway, "--threads", str(threads), "--out", str(dst)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        maps: np.ndarray = np.load(dst)
    return maps


def int8_cache(
    cache: DescriptorCache,
    blob: Path,
    bino: Path,
    parts: Path,
    chunk: int,
    threads: int,
    data_dir: Path | None,
) -> DescriptorCache:
    sampler = HeadSampler(DataConfig.from_dict(cache.meta["data"]), cache.meta["seed"], data_dir)
    parts.mkdir(parents=True, exist_ok=True)
    lefts, rights = [], []
    start = time.perf_counter()
    for lo in range(0, cache.count, chunk):
        hi = min(cache.count, lo + chunk)
        part = parts / f"{lo:06d}_{hi:06d}.pt"
        if not part.is_file():
            samples = sampler.samples(range(lo, hi))
            if not same_labels(samples, cache.data.label[lo:hi]):
                raise SystemExit(f"error: samples {lo}..{hi} do not regenerate the cache's labels")
            maps = describe(bino, blob, cache.pathway, crop_stack(samples), threads)
            pair = torch.from_numpy(maps).half()
            tmp = part.with_name(part.name + ".partial")
            torch.save({"left": pair[:, 0].clone(), "right": pair[:, 1].clone()}, tmp)
            tmp.replace(part)
        state = torch.load(part, map_location="cpu")
        lefts.append(state["left"])
        rights.append(state["right"])
        rate = (hi - lo) / max(time.perf_counter() - start, 1e-9)
        start = time.perf_counter()
        print(
            f"int8 cache: {hi}/{cache.count} samples ({rate:.1f}/s this chunk)",
            flush=True,
        )
    data = replace(cache.data, left=torch.cat(lefts), right=torch.cat(rights))
    if data.left.shape != cache.data.left.shape:
        raise SystemExit(
            f"error: engine maps {tuple(data.left.shape)} differ from the cache's "
            f"{tuple(cache.data.left.shape)}"
        )
    meta = dict(cache.meta)
    meta["maps"] = "int8"
    meta["blob_sha256"] = hashlib.sha256(blob.read_bytes()).hexdigest()
    meta["float_cache"] = cache.meta.get("encoder_path", "")
    return DescriptorCache(meta, data)


def map_cosine(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean cosine between two caches' maps, per token (how far the engine moved them)."""
    cos = torch.nn.functional.cosine_similarity(a.float(), b.float(), dim=-1)
    return float(cos.mean())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--cache", type=Path, required=True, help="float cache (head_cache.py)")
    p.add_argument("--out", type=Path, required=True, help="int8 cache to write")
    p.add_argument("--blob", type=Path, default=REPO / "weights" / "bino_int8.bin")
    p.add_argument("--bino", type=Path, default=None, help="bino binary (default: release)")
    p.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    p.add_argument("--chunk", type=int, default=250, help="crops per bino call")
    p.add_argument("--threads", type=int, default=2, help="bino worker threads")
    args = p.parse_args(argv)
    bino = args.bino or default_bino()
    for path, what in ((args.cache, "cache"), (args.blob, "blob"), (bino, "bino binary")):
        if not path.is_file():
            sys.exit(f"error: {what} {path} does not exist")
    if args.chunk < 1:
        sys.exit(f"error: --chunk {args.chunk} must be at least 1")
    cache = load_cache(args.cache)
    parts = args.out.with_name(args.out.name + ".parts")
    out = int8_cache(cache, args.blob, bino, parts, args.chunk, args.threads, args.data)
    cosine = map_cosine(out.data.left[:256], cache.data.left[:256])
    out.meta["float_cosine_first256"] = round(cosine, 4)
    save_cache(out, args.out)
    print(f"wrote {args.out}: {out.count} samples; cosine to the float maps {cosine:.4f}")


if __name__ == "__main__":
    main()
