"""Re-encoding a descriptor cache by the int8 engine (`int8_cache`), with a stand-in `bino`."""

from __future__ import annotations

import stat
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TINY_SYNTHETIC_DATA, save_tiny_cache

from bino_train.export import random_encoder
from bino_train.head_cache import load_cache
from bino_train.head_data import HeadSampler
from bino_train.head_train import SMOKE_ENCODER
from bino_train.int8_cache import crop_stack, int8_cache, main, same_labels

FAKE_BINO = """#!{python}
# Stand-in for `bino describe`: each map token is its crop view's mean grey (DIM 32).
import sys, numpy as np
args = dict(zip(sys.argv[2::2], sys.argv[3::2]))
crops = np.load(args["--crops"])
n, _, h, w = crops.shape
means = crops.mean(axis=(2, 3))
maps = np.broadcast_to(means[:, :, None, None, None], (n, 2, h // 4, w // 4, 32))
np.save(args["--out"], maps.astype(np.float32))
"""


def fake_bino(tmp_path: Path) -> Path:
    path = tmp_path / "bino"
    path.write_text(FAKE_BINO.format(python=sys.executable))
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def tiny_cache(tmp_path: Path, count: int = 6) -> Path:
    path = tmp_path / "float.pt"
    save_tiny_cache(path, random_encoder(0, SMOKE_ENCODER), TINY_SYNTHETIC_DATA, 3, count)
    return path


def test_regenerated_samples_are_the_cache_crops_and_labels(tmp_path: Path) -> None:
    cache = load_cache(tiny_cache(tmp_path))
    samples = HeadSampler(TINY_SYNTHETIC_DATA, 3, None).samples(range(cache.count))
    stack = crop_stack(samples)
    assert stack.shape == (6, 2, 32, 96) and stack.dtype == np.float32
    assert same_labels(samples, cache.data.label)
    moved = cache.data.label.clone()
    moved[torch.isfinite(moved)] += 0.25
    assert not same_labels(samples, moved)
    other_seed = HeadSampler(TINY_SYNTHETIC_DATA, 4, None).samples(range(cache.count))
    assert not same_labels(other_seed, cache.data.label)


def test_maps_are_replaced_and_everything_else_kept(tmp_path: Path) -> None:
    src = tiny_cache(tmp_path)
    bino, blob = fake_bino(tmp_path), tmp_path / "blob.bin"
    blob.write_bytes(b"weights")
    out = tmp_path / "int8.pt"
    main(
        ["--cache", str(src), "--out", str(out), "--blob", str(blob), "--bino", str(bino)]
        + ["--chunk", "4"]
    )
    cache, float_cache = load_cache(out), load_cache(src)
    assert cache.data.left.shape == (6, 8, 24, 32)
    assert cache.meta["maps"] == "int8" and len(cache.meta["blob_sha256"]) == 64
    assert cache.meta["encoder_sha256"] == float_cache.meta["encoder_sha256"]
    for name in ("label", "weight", "images", "synthetic"):
        kept, original = getattr(cache.data, name), getattr(float_cache.data, name)
        assert torch.equal(kept.nan_to_num(-1.0), original.nan_to_num(-1.0)), name
    # The stand-in's maps are the mean grey of the crop the encoder reads: the views after the
    # nuisances (the cache keeps the clean ones for the photometric terms), left then right.
    views = crop_stack(HeadSampler(TINY_SYNTHETIC_DATA, 3, None).samples(range(6)))
    for v, maps in enumerate((cache.data.left, cache.data.right)):
        want = torch.from_numpy(views[:, v].mean(axis=(1, 2)))
        assert torch.allclose(maps[:, 0, 0, 0].float(), want, atol=1e-3), v


def test_an_interrupted_build_resumes_from_its_parts(tmp_path: Path) -> None:
    cache = load_cache(tiny_cache(tmp_path))
    bino, blob, parts = fake_bino(tmp_path), tmp_path / "blob.bin", tmp_path / "parts"
    blob.write_bytes(b"weights")
    first = int8_cache(cache, blob, bino, parts, 4, 1, None)
    assert len(list(parts.glob("*.pt"))) == 2
    stamps = {p: p.stat().st_mtime_ns for p in parts.glob("*.pt")}
    again = int8_cache(cache, blob, bino, parts, 4, 1, None)
    assert torch.equal(first.data.left, again.data.left)
    assert {p: p.stat().st_mtime_ns for p in parts.glob("*.pt")} == stamps, "parts rewritten"


def test_a_cache_that_does_not_regenerate_is_refused(tmp_path: Path) -> None:
    cache = load_cache(tiny_cache(tmp_path))
    wrong = replace(cache, meta={**cache.meta, "seed": 99})
    bino, blob = fake_bino(tmp_path), tmp_path / "blob.bin"
    blob.write_bytes(b"weights")
    with pytest.raises(SystemExit, match="do not regenerate"):
        int8_cache(wrong, blob, bino, tmp_path / "parts", 4, 1, None)
