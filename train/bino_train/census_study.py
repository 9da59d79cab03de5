"""The command line the census studies share (`census_selector`, `census_rerank`): the width,
the output JSON, the encoder and native head (the shipped ones by default), the data folder, the
clean labeled pairs and the torch threads; the models loaded once; the result written with its
run's settings and seconds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import torch

from .head import StereoHead, head_candidates, load_head, with_candidates
from .labeled import LABELED_HOLDOUT
from .model import BinoEncoder

ROOT = Path(__file__).resolve().parents[1]


def study_parser(doc: str | None) -> argparse.ArgumentParser:
    """The studies' shared arguments; a study adds its own."""
    p = argparse.ArgumentParser(
        description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--width", type=int, required=True, help="view width (160 or 320)")
    p.add_argument("--out", type=Path, required=True, help="JSON to write")
    p.add_argument(
        "--encoder",
        type=Path,
        default=ROOT / "checkpoints/p7_short_blur/student_0030000.pt",
        help="encoder checkpoint",
    )
    p.add_argument(
        "--head",
        type=Path,
        default=ROOT / "checkpoints/hgt40nat_p7_mid/last.pt",
        help="native head checkpoint (the shipped one by default)",
    )
    p.add_argument("--data", type=Path, help="folder with PAIRS.tsv (default ../shared/data)")
    p.add_argument("--pairs", nargs="+", default=list(LABELED_HOLDOUT), help="labeled train pairs")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    return p


def load_models(args: argparse.Namespace) -> tuple[BinoEncoder, StereoHead]:
    """The encoder and the native head searching the width's candidates, in eval mode."""
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    from .export import load_encoder

    encoder = load_encoder(args.encoder).eval()
    head = with_candidates(load_head(args.head), head_candidates(args.width)).eval()
    return encoder, head


def write_result(
    args: argparse.Namespace, head: StereoHead, study: dict[str, Any], start: float
) -> dict[str, Any]:
    """`study` with the run's settings and seconds since `start`, written to `--out`."""
    result: dict[str, Any] = {
        "width": args.width,
        "candidates": head.cfg.max_disp,
        "encoder": str(args.encoder),
        "head": str(args.head),
        **study,
    }
    result["seconds"] = round(time.perf_counter() - start, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result
