#!/usr/bin/env python3
"""Renders every table of measured numbers in README.md and docs/*.md from the committed
measurement files, so each figure has one source.

    python3 scripts/render_docs.py            # rewrite the marked regions in place
    python3 scripts/render_docs.py --check    # exit 1 if a doc differs from a fresh render
    python3 scripts/render_docs.py --list     # the regions, their files and their sources
    python3 scripts/render_docs.py --self-test

A region is the text between `<!-- render:NAME -->` and `<!-- /render:NAME -->` on lines of
their own; NAME picks a renderer of `RENDERERS` below (the renderers live in `scripts/rendering/`:
`accuracy.py`, `speed.py`, `firmware.py`, and their shared `common.py`). Sources: `train/checkpoints/metrics/*.json` (bino eval,
compare, bench, the Python probe and benchmark), `firmware-sim/measured/*.json` (the QEMU runs
and `bino budget`), `weights/MANIFEST.json` and the shipped files' sizes. Prose should quote a
rendered table rather than restate its figures. Python 3.11 standard library only.
"""

from __future__ import annotations

import argparse
import io
import json
import re
import sys
import tempfile
from collections.abc import Callable, Sequence
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

from rendering.accuracy import (
    accuracy_headline,
    census_vs_learned,
    eval_refined,
    eval_unrefined,
    heldout_labeled,
    int8_vs_float,
    native_checks,
    native_float,
    native_vs_export,
    nuisance,
    occlusion_export,
    pck_benchmark,
    probe_and_head,
    reproduction,
)
from rendering.common import (
    MANIFEST,
    MARK,
    METRICS,
    OPEN,
    README_MAX_LINES,
    ROOT,
    Sources,
)
from rendering.firmware import (
    blob_size,
    board_e7_frame,
    board_headline,
    board_frames,
    board_pathways,
    board_presets,
    board_regions,
    fw_camera,
    fw_cycle_model,
    fw_frame_check,
    fw_frames,
    fw_memory,
    fw_stages,
    fw_targets,
    training_summary,
    weights_files,
)
from rendering.speed import BENCH_RUNS, bench_table, run_timing, speed_headline

RENDERERS: dict[str, Callable[[Sources], str]] = {
    "census-vs-learned": census_vs_learned,
    "board-regions": board_regions,
    "board-e7-frame": board_e7_frame,
    "accuracy-headline": accuracy_headline,
    "board-headline": board_headline,
    "speed-headline": speed_headline,
    "eval-unrefined": eval_unrefined,
    "eval-refined": eval_refined,
    "probe-and-head": probe_and_head,
    "int8-vs-float": int8_vs_float,
    "pck-benchmark": pck_benchmark,
    "nuisance-w160": nuisance("w160"),
    "nuisance-w320": nuisance("w320"),
    "native-nuisance-w160": nuisance("w160", "native_nuisance"),
    "native-nuisance-w320": nuisance("w320", "native_nuisance"),
    "occlusion-w160": occlusion_export,
    "native-vs-export": native_vs_export,
    "native-float": native_float,
    "board-pathways": board_pathways,
    "board-presets": board_presets,
    "board-frames": board_frames,
    "native-checks": native_checks,
    "heldout-labeled": heldout_labeled,
    "reproduction": reproduction,
    "bench": bench_table,
    "run-timing": run_timing,
    "fw-memory": fw_memory,
    "fw-stages": fw_stages,
    "fw-targets": fw_targets,
    "fw-camera": fw_camera,
    "fw-cycle-model": fw_cycle_model,
    "fw-frames": fw_frames,
    "fw-frame-check": fw_frame_check,
    "weights-files": weights_files,
    "training-summary": training_summary,
    "blob-size": blob_size,
}


# ---------------------------------------------------------------- documents


@dataclass
class Outcome:
    text: str
    stale: list[str]
    sources: dict[str, list[str]]


def render_text(text: str, root: Path, rel: str) -> Outcome:
    """The document with every region rendered; which regions changed; each region's sources."""
    opened = OPEN.findall(text)
    closed = {m.group(1) for m in MARK.finditer(text)}
    for name in opened:
        if name not in closed:
            raise SystemExit(f"{rel}: region {name} has no closing <!-- /render:{name} --> line")
    stale: list[str] = []
    sources: dict[str, list[str]] = {}

    def replace(m: re.Match[str]) -> str:
        name = m.group(1)
        if name not in RENDERERS:
            raise SystemExit(f"{rel}: region {name} has no renderer in scripts/render_docs.py")
        src = Sources(root)
        body = RENDERERS[name](src).rstrip("\n") + "\n"
        sources[name] = src.used
        if m.group(2) != body:
            stale.append(name)
        return f"<!-- render:{name} -->\n{body}<!-- /render:{name} -->"

    return Outcome(MARK.sub(replace, text), stale, sources)


def documents(root: Path) -> list[Path]:
    docs = sorted((root / "docs").glob("*.md")) if (root / "docs").is_dir() else []
    return [p for p in [root / "README.md", *docs] if p.is_file()]


def main(argv: Sequence[str] | None = None, root: Path = ROOT) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument(
        "--check", action="store_true", help="exit 1 if a committed doc differs from a fresh render"
    )
    mode.add_argument(
        "--list", action="store_true", help="print each region, its file and its sources"
    )
    mode.add_argument("--self-test", action="store_true", help="run this script's own tests")
    args = ap.parse_args(argv)
    if args.self_test:
        return self_test()
    readme = root / "README.md"
    if args.check and readme.is_file():
        lines = len(readme.read_text(encoding="utf-8").splitlines())
        if lines > README_MAX_LINES:
            print(f"README.md: {lines} lines, more than {README_MAX_LINES}", file=sys.stderr)
            return 1
    docs = documents(root)
    if not docs:
        # A wrong root would otherwise pass --check with nothing checked.
        print(f"no README.md or docs/*.md under {root}", file=sys.stderr)
        return 1
    for path in docs:
        rel = str(path.relative_to(root))
        text = path.read_text(encoding="utf-8")
        out = render_text(text, root, rel)
        if args.list:
            for name, used in out.sources.items():
                print(f"{rel}\t{name}\t{', '.join(used)}")
        elif args.check:
            if out.stale:
                print(
                    f"{rel}: region {out.stale[0]} differs from a fresh render of its "
                    "measurement files "
                    f"(run python3 scripts/render_docs.py and commit)",
                    file=sys.stderr,
                )
                return 1
        elif out.text != text:
            path.write_text(out.text, encoding="utf-8")
            print(f"{rel}: rendered {', '.join(out.stale)}")
    return 0


def self_test() -> int:
    """Renders a document against a tiny measurement tree: fill, check, detect an edit."""
    quiet = io.StringIO()
    with tempfile.TemporaryDirectory() as tmp, redirect_stdout(quiet), redirect_stderr(quiet):
        root = Path(tmp)
        (root / METRICS).mkdir(parents=True)
        (root / "docs").mkdir()
        b = {
            "cpu": "Test CPU",
            "x86_kernels": "avx2",
            "threads": 1,
            "blob_sha256": "ab" * 32,
            "int8": {"median_s": 0.01, "min_s": 0.009, "gmac_per_s": 1.0, "runs_s": [0.01]},
            "tract_f32": {"median_s": 0.03, "min_s": 0.02, "gmac_per_s": 0.5, "runs_s": [0.03]},
            "tract_over_int8": 3.0,
        }
        (root / "weights").mkdir()
        (root / MANIFEST).write_text(
            json.dumps({"files": {"bino_int8.bin": "ab" * 32}}), encoding="utf-8"
        )
        for name in BENCH_RUNS:
            (root / METRICS / f"{name}.json").write_text(json.dumps(b), encoding="utf-8")
        doc = root / "docs" / "t.md"
        doc.write_text(
            "Intro.\n\n<!-- render:bench -->\nold\n<!-- /render:bench -->\n\nEnd.\n",
            encoding="utf-8",
        )
        assert main(["--check"], root) == 1, "a stale region fails --check"
        assert main([], root) == 0
        text = doc.read_text(encoding="utf-8")
        assert "| int8 engine (avx2 kernels) | 10.0 ms | 9.0 ms | 1.0 |" in text, text
        assert text.startswith("Intro.\n\n<!-- render:bench -->\n") and text.endswith(
            "<!-- /render:bench -->\n\nEnd.\n"
        )
        assert main(["--check"], root) == 0, "a fresh render passes --check"
        doc.write_text(text.replace("10.0 ms", "11.0 ms"), encoding="utf-8")
        assert main(["--check"], root) == 1, "a hand edit inside a region fails --check"
        doc.write_text("<!-- render:nope -->\n<!-- /render:nope -->\n", encoding="utf-8")
        try:
            main(["--check"], root)
        except SystemExit as e:
            assert "no renderer" in str(e), e
        else:
            raise AssertionError("an unknown region is an error")
    print("render_docs self-test: ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
