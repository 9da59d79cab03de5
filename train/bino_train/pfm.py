"""Reading grayscale PFM (portable float map), the ground truth of Middlebury 2014 and ETH3D.

The same strict rules as the Rust reader (`std-host/src/pfm.rs`), so both accept the same files:
`Pf` only (a colour `PF` map is refused, not reduced to a channel); width and height at most
`MAX_SIDE`, checked before any pixel is read; a non-zero scale whose sign gives the byte order
(negative: little-endian) and whose magnitude is not applied; one whitespace byte; then exactly
width * height float32s, rows from the bottom of the image up. Values come back as stored, `inf`
and NaN included, top row first. OpenCV reads PFM too, but would take a colour map as BGR and
does not bound the size; the tests check that it agrees on the files both accept.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

MAX_SIDE = 16_384
"""Widest and tallest map read, as `image_io::MAX_IMAGE_SIDE` on the Rust side."""

_WHITESPACE = b" \t\n\r\x0c"
_TOKEN = re.compile(rb"[ \t\n\r\x0c]*([^ \t\n\r\x0c]{1,32})")
_UNSIGNED = re.compile(rb"\+?[0-9]{1,10}")


def read_pfm(path: Path) -> NDArray[np.float32]:
    """(H, W) float32 of the PFM file `path`, top row first; a ValueError names the file."""
    data = Path(path).read_bytes()
    try:
        return decode_pfm(data)
    except ValueError as e:
        raise ValueError(f"cannot decode ground truth {path} (PFM): {e}") from None


def decode_pfm(data: bytes) -> NDArray[np.float32]:
    """(H, W) float32 of the bytes of a grayscale PFM file, top row first."""
    pos = 0

    def token(what: str) -> bytes:
        nonlocal pos
        match = _TOKEN.match(data, pos)
        if match is None:
            raise ValueError(f"truncated header (no {what})")
        pos = match.end()
        if pos < len(data) and data[pos] not in _WHITESPACE:
            raise ValueError(f"bad {what} in the header (too long)")
        return match.group(1)

    magic = token("magic")
    if magic == b"PF":
        raise ValueError("colour PFM (PF): a disparity map has one channel (Pf)")
    if magic != b"Pf":
        raise ValueError("not a PFM file (it must start with Pf)")
    sides = []
    for what in ("width", "height"):
        text = token(what)
        if not _UNSIGNED.fullmatch(text) or int(text) >= 2**32:
            raise ValueError(f"bad {what} {text.decode(errors='replace')!r} in the header")
        sides.append(int(text))
    width, height = sides
    if width == 0 or height == 0:
        raise ValueError(f"empty image ({width}x{height})")
    if width > MAX_SIDE or height > MAX_SIDE:
        raise ValueError(
            f"declares {width}x{height} pixels, more than the {MAX_SIDE}x{MAX_SIDE} limit"
        )
    text = token("scale")
    try:
        scale = float(text)
    except ValueError:
        raise ValueError(f"bad scale {text.decode(errors='replace')!r} in the header") from None
    if not np.isfinite(scale) or scale == 0.0:
        raise ValueError(f"scale {scale} gives no byte order (it must be a non-zero number)")
    if pos >= len(data):
        raise ValueError("truncated header (no line end after the scale)")
    pos += 1
    need, have = width * height * 4, len(data) - pos
    if have < need:
        raise ValueError(f"truncated: {have} bytes of pixels, {width}x{height} needs {need}")
    if have > need:
        raise ValueError(
            f"{have - need} bytes after the {width}x{height} pixels (wrong size in the header?)"
        )
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    stored = np.frombuffer(data, dtype=dtype, count=width * height, offset=pos)
    return np.ascontiguousarray(stored.reshape(height, width)[::-1], dtype=np.float32)


def encode_pfm(image: NDArray[np.float32]) -> bytes:
    """The bytes of a grayscale little-endian PFM file of a (H, W) float32 map (top row first)."""
    if image.ndim != 2 or 0 in image.shape:
        raise ValueError(f"a PFM map is (H, W) and non-empty, got shape {image.shape}")
    height, width = image.shape
    rows = np.ascontiguousarray(image[::-1], dtype="<f4")
    return f"Pf\n{width} {height}\n-1.0\n".encode() + rows.tobytes()
