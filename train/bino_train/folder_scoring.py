"""The command line the readout-variant studies share (`check_variants`, `readout_variants`,
`census_companion`): an encoder and a head, scored by a study's `score_folder` on each labeled
`val` folder at that folder's width (the head's candidates set by `head.head_candidates`), every
variant's mean printed and the JSON written after each folder.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from .head import StereoHead, head_candidates, load_head, with_candidates
from .model import BinoEncoder
from .pairs import load_gray, load_pairs
from .probe import mean_metrics

Scores = dict[str, dict[str, Any]]
"""{variant: {"mean": metrics, "pairs": {pair: metrics}}}."""

ScoreFolder = Callable[[BinoEncoder, StereoHead, Path], Scores]


def folder_width(folder: Path) -> int:
    """The views' width of a folder's first pair (every pair of a folder shares it)."""
    first = load_pairs(folder, "val")[0]
    return int(load_gray(first.left).shape[1])


def per_variant(names: list[str], per: dict[str, list[dict[str, float]]]) -> Scores:
    """Each variant's mean over the pairs `names` and its metrics per pair."""
    return {
        name: {"mean": mean_metrics(rows), "pairs": dict(zip(names, rows, strict=True))}
        for name, rows in per.items()
    }


def epe_bad1tok(m: dict[str, float]) -> str:
    """`epe / bad1tok` of a variant's mean metrics."""
    return f"{m['epe']:.3f} / {m['bad1tok']:.2f}"


def run_cli(
    description: str,
    head_help: str,
    score_folder: ScoreFolder,
    argv: Sequence[str] | None = None,
    summary: Callable[[dict[str, float]], str] = epe_bad1tok,
) -> dict[str, Any]:
    """Parses `argv`, scores every `--folders` folder with `score_folder`, prints each variant's
    `summary`, writes `--out` after each folder (a long run keeps what it measured); returns
    the result."""
    p = argparse.ArgumentParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--encoder", type=Path, required=True, help="encoder the head was trained on")
    p.add_argument("--head", type=Path, required=True, help=head_help)
    p.add_argument("--folders", type=Path, nargs="+", required=True, help="labeled val folders")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--out", type=Path, help="also write the JSON here")
    args = p.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    from .export import load_encoder

    encoder = load_encoder(args.encoder).eval()
    loaded = load_head(args.head).eval()
    result: dict[str, Any] = {"head": str(args.head), "folders": {}}
    for folder in args.folders:
        width = folder_width(folder)
        head: StereoHead = with_candidates(loaded, head_candidates(width)).eval()
        scores = score_folder(encoder, head, folder)
        result["folders"][str(folder)] = {"width": width, "candidates": head.cfg.max_disp, **scores}
        print(f"{folder} (w{width}):", flush=True)
        for name, s in scores.items():
            print(f"  {name:28s} {summary(s['mean'])}", flush=True)
        if args.out is not None:
            args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result
