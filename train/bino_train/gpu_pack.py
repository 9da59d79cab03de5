"""A small copy of the train split for a machine the data folder cannot travel to (a GPU lease).

    python -m bino_train.gpu_pack --out gpu_pack            # from ../shared/data
    python -m bino_train.gpu_pack --out gpu_pack --quality 90 --max-width 672

The pack is itself a data folder: its `PAIRS.tsv` lists the train pairs only (read through
`training_pairs`, so no eval image can enter it) with their pack paths and pack sizes, and
`--data PACK` works wherever a train-split data folder does. Each view is stored grayscale
(the rule of `pairs.load_gray_u8`), area-downscaled to at most `--max-width` (the largest
width the pretraining crops are cut from, `AugmentConfig.max_width`; the height rounds as in
`augment.ImageStore.resized`, so the pack holds what the crop sampler would build at that
width), as a baseline JPEG. `PACK.json` records the source index's sha256, the settings and
the byte count. JPEG is lossy: on the current train split the default quality 85 gives a
mean absolute error of 2.0 grey levels against the downscaled original (1.6 at quality 90),
well below the training noise (sigma up to 0.03, about 8 levels); the pack is 11.7 MB
(14.5 MB at quality 90).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .augment import AugmentConfig
from .pairs import COLUMNS, DEFAULT_DATA_DIR, INDEX_NAME, Pair, load_gray_u8, training_pairs

PACK_INFO = "PACK.json"
DEFAULT_QUALITY = 85


@dataclass(frozen=True)
class PackedPair:
    pair_id: str
    dataset: str
    left: str
    right: str
    width: int
    height: int


def downscale(image: NDArray[np.uint8], max_width: int) -> NDArray[np.uint8]:
    """Area-resize to `max_width` when wider (height rounded as ImageStore.resized does)."""
    h, w = image.shape
    if w <= max_width:
        return image
    height = int(math.floor(h * max_width / w + 0.5))
    return np.asarray(cv2.resize(image, (max_width, height), interpolation=cv2.INTER_AREA))


def safe_name(pair_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", pair_id)


def encode_jpeg(image: NDArray[np.uint8], quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return bytes(buf.tobytes())


def pack_pair(pair: Pair, out: Path, max_width: int, quality: int) -> PackedPair:
    names = []
    shape: tuple[int, ...] = ()
    for view, path in (("l", pair.left), ("r", pair.right)):
        image = downscale(load_gray_u8(path), max_width)
        if shape and image.shape != shape:
            raise ValueError(f"{pair.pair_id}: views differ in size")
        shape = image.shape
        name = f"train/{safe_name(pair.pair_id)}_{view}.jpg"
        (out / name).write_bytes(encode_jpeg(image, quality))
        names.append(name)
    return PackedPair(pair.pair_id, pair.dataset, names[0], names[1], shape[1], shape[0])


def write_index(rows: list[PackedPair], out: Path) -> None:
    with (out / INDEX_NAME).open("w", newline="") as f:
        writer = csv.writer(f, delimiter="\t", lineterminator="\n")
        writer.writerow(COLUMNS)
        for r in rows:
            writer.writerow(
                [r.pair_id, "train", r.dataset, r.left, r.right, "", "", "", "", r.width, r.height]
            )


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def make_pack(data_dir: Path | None, out: Path, max_width: int, quality: int) -> dict[str, object]:
    """Write the pack; returns what PACK.json holds."""
    if not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality {quality} outside 1..100")
    pairs = training_pairs(data_dir)
    (out / "train").mkdir(parents=True, exist_ok=True)
    for stale in (out / "train").glob("*.jpg"):
        stale.unlink()
    rows = [pack_pair(p, out, max_width, quality) for p in pairs]
    write_index(rows, out)
    index = (data_dir if data_dir is not None else DEFAULT_DATA_DIR) / INDEX_NAME
    info: dict[str, object] = {
        "source_index_sha256": hashlib.sha256(index.read_bytes()).hexdigest(),
        "pairs": len(rows),
        "split": "train",
        "max_width": max_width,
        "quality": quality,
        "format": "grayscale baseline JPEG",
    }
    (out / PACK_INFO).write_text(json.dumps(info, indent=1) + "\n")
    info["bytes"] = folder_bytes(out)
    (out / PACK_INFO).write_text(json.dumps(info, indent=1) + "\n")
    return info


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="pack folder (an ignored path)")
    p.add_argument("--data", type=Path, default=None, help="source data folder with PAIRS.tsv")
    p.add_argument("--max-width", type=int, default=AugmentConfig().max_width)
    p.add_argument("--quality", type=int, default=DEFAULT_QUALITY, help="JPEG quality 1..100")
    args = p.parse_args(argv)
    info = make_pack(args.data, args.out, args.max_width, args.quality)
    print(json.dumps(info))


if __name__ == "__main__":
    main()
