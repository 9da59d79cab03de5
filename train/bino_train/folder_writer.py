"""Writing a data folder `bino eval --data DIR --split val` scores: each pair's views as 8-bit
PNGs and its ground truth as a PFM (NaN where unknown), indexed by a PAIRS.tsv of the columns
`pairs.COLUMNS` (`labeled_folder`, `val_folder`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from .pairs import COLUMNS, SplitError
from .pfm import encode_pfm

SPLIT = "val"


def write_pair(
    out: Path, pair_id: str, dataset: str, views: list[np.ndarray], gt: np.ndarray
) -> str:
    """Write one pair's two views and ground truth into `out`; returns its PAIRS.tsv row."""
    names = [f"{pair_id}_{v}.png" for v in ("left", "right")]
    for name, image in zip(names, views, strict=True):
        if not cv2.imwrite(str(out / name), image):
            raise OSError(f"cannot write {out / name}")
    (out / f"{pair_id}_gt.pfm").write_bytes(encode_pfm(gt.astype(np.float32)))
    height, width = views[0].shape
    fields = [pair_id, SPLIT, dataset, *names, f"{pair_id}_gt.pfm"]
    return "\t".join([*fields, "pfm", "1", "", str(width), str(height)])


def write_index(out: Path, rows: list[str]) -> None:
    """Write the folder's PAIRS.tsv: the header, then `rows`."""
    (out / "PAIRS.tsv").write_text("\n".join(["\t".join(COLUMNS), *rows]) + "\n")


@contextmanager
def errors_as_one_line(tool: str) -> Iterator[None]:
    """A folder tool's bad data (a missing or unreadable file, a bad index) as one line naming
    the tool and the problem, not a traceback."""
    try:
        yield
    except (OSError, ValueError, SplitError) as err:
        raise SystemExit(f"error: {tool}: {err}") from None
