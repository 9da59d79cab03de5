"""weights/MANIFEST.json: what was shipped, how it was trained, and what it measured.

    python -m bino_train.manifest --pretrain-run runs/NAME --head-run runs/HEAD \
        --metrics-dir runs/metrics --experiments experiments.json --out ../weights/MANIFEST.json

Every file in the weights folder gets its sha256; the recipe comes from the checkpoints, the
metrics from the JSON written by the evaluation commands, and the list of what was tried
(with what it did) from `experiments.json`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

import torch

from .pairs import training_pairs

LICENCE = (
    "Trained on ../shared/data train-split pairs: Karlsruhe sequences and ETH3D are CC BY-NC-SA "
    "(non-commercial), Middlebury is free for research with citation, OAK-D captures are MIT "
    "(see ../shared/data/DATA.md). These weights inherit the non-commercial restriction."
)


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def file_hashes(folder: Path) -> dict[str, str]:
    """sha256 of every shipped artifact in `folder` (documentation and the manifest excluded)."""
    return {
        p.name: sha256(p)
        for p in sorted(folder.iterdir())
        if p.is_file() and p.name != "MANIFEST.json" and p.suffix != ".md"
    }


def run_summary(run: Path, upto_pairs: int | None = None, role: str = "teacher") -> dict[str, Any]:
    """Recipe and progress of a training run, from its last checkpoint and log.

    `upto_pairs` names a pretraining run's snapshot (`<role>_<pairs>.pt`, role teacher or
    student) as the shipped weights, when the run went on past its best probe or its student
    probed lower: the recipe comes from `last.pt` (or, for a finished run whose `last.pt` left
    the tree, from the snapshot's own `train_config`), the progress (steps, pairs, seconds,
    evaluations) stops at the snapshot.
    """
    last = run / "last.pt"
    if not last.is_file() and upto_pairs is not None:
        last = run / f"{role}_{upto_pairs:07d}.pt"
    state = torch.load(last, map_location="cpu", weights_only=False)
    if "train_config" not in state:
        raise SystemExit(f"error: {last}: no train_config (a run's last.pt or a full snapshot)")
    summary: dict[str, Any] = {
        "run": run.name,
        "train_config": state.get("train_config"),
        "steps": state.get("step"),
        "pairs_seen": state.get("pairs_seen"),
        "train_seconds": state.get("train_seconds"),
    }
    if "interpolated" in state:
        # head_interpolate's output: the weights lie between two runs' heads.
        summary["interpolated"] = state["interpolated"]
    log = run / "log.jsonl"
    records = []
    if log.is_file():
        records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
    if upto_pairs is not None:
        records = snapshot_records(run, records, upto_pairs, summary, role)
    if records:
        summary["sessions"] = sum(1 for r in records if r.get("kind") == "start")
        summary["evaluations"] = [r for r in records if r.get("kind") == "eval"]
    return summary


def snapshot_records(
    run: Path,
    records: list[dict[str, Any]],
    pairs: int,
    summary: dict[str, Any],
    role: str = "teacher",
) -> list[dict[str, Any]]:
    """The log up to the `role` snapshot at `pairs`; moves `summary`'s progress there."""
    snapshot = run / f"{role}_{pairs:07d}.pt"
    if not snapshot.is_file():
        raise SystemExit(f"error: {snapshot}: no {role} snapshot at {pairs} pairs")
    evals = [r for r in records if r.get("kind") == "eval" and r.get("pairs") == pairs]
    if not evals:
        raise SystemExit(f"error: {run / 'log.jsonl'}: no evaluation at {pairs} pairs")
    kept = [r for r in records if r.get("pairs", 0) <= pairs]
    # `wall_s` counts from each invocation's start: a run's time is the sum of its sessions'.
    seconds, session = 0.0, 0.0
    for r in kept:
        if r.get("kind") == "start":
            seconds, session = seconds + session, 0.0
        session = max(session, float(r.get("wall_s", 0.0)))
    summary.update(
        shipped_checkpoint=snapshot.name,
        steps=evals[0].get("step"),
        pairs_seen=pairs,
        train_seconds=round(seconds + session, 1),
        run_pairs_seen=summary["pairs_seen"],
    )
    return kept


def hardware() -> dict[str, str]:
    cpu = platform.processor() or platform.machine()
    try:
        info = Path("/proc/cpuinfo").read_text()
        cpu = next(
            line.split(":", 1)[1].strip() for line in info.splitlines() if "model name" in line
        )
    except (OSError, StopIteration):
        pass
    return {
        "cpu": cpu,
        "torch_threads": str(torch.get_num_threads()),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none",
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "platform": platform.platform(),
    }


def git_commit(repo: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def collect_metrics(folder: Path) -> dict[str, Any]:
    """Every `NAME.json` of `folder` as `{NAME: content}`, in name order."""
    if not folder.is_dir():
        raise SystemExit(f"error: metrics folder {folder} does not exist")
    metrics: dict[str, Any] = {}
    for path in sorted(folder.glob("*.json")):
        try:
            metrics[path.stem] = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            raise SystemExit(f"error: {path} is not valid JSON: {err}") from err
    return metrics


def check_head_metrics(metrics: dict[str, Any], head: dict[str, Any] | None) -> None:
    """Refuses head metrics measured on another head than the shipped one.

    `head_eval_w160` records the step of the head it scored; a head trained on after the
    metric was written would otherwise ship beside another head's figures."""
    scored = metrics.get("head_eval_w160")
    if head is None or not isinstance(scored, dict) or "head_step" not in scored:
        return
    if scored["head_step"] != head["steps"]:
        raise SystemExit(
            f"error: metrics head_eval_w160 scored a head at step {scored['head_step']}, the "
            f"shipped head ({head['run']}) is at step {head['steps']}: re-run bino_train.head_eval"
        )


def build_manifest(
    weights: Path,
    pretrain_run: Path,
    head_run: Path | None,
    metrics: dict[str, Any],
    experiments: list[dict[str, Any]],
    data_dir: Path | None,
    native_head_run: Path | None = None,
    pretrain_pairs: int | None = None,
    pretrain_role: str = "teacher",
) -> dict[str, Any]:
    pairs = training_pairs(data_dir)
    head = run_summary(head_run) if head_run is not None else None
    check_head_metrics(metrics, head)
    return {
        "files": file_hashes(weights),
        "code_commit": git_commit(weights.parent),
        "hardware": hardware(),
        "pretraining": run_summary(pretrain_run, pretrain_pairs, pretrain_role),
        "head_training": head,
        "native_head_training": (
            run_summary(native_head_run) if native_head_run is not None else None
        ),
        "training_pairs": [p.pair_id for p in pairs],
        "metrics": metrics,
        "experiments": experiments,
        "licence": LICENCE,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--pretrain-run", type=Path, required=True)
    parser.add_argument(
        "--pretrain-pairs",
        type=int,
        help="ship the run's snapshot at this many pairs (<role>_<pairs>.pt), not last.pt",
    )
    parser.add_argument(
        "--pretrain-role",
        choices=("teacher", "student"),
        default="teacher",
        help="which encoder's snapshot --pretrain-pairs names (default teacher)",
    )
    parser.add_argument("--head-run", type=Path)
    parser.add_argument("--native-head-run", type=Path, help="the native pathway's head run")
    parser.add_argument("--metrics", type=Path, help="JSON of measured metrics")
    parser.add_argument(
        "--metrics-dir", type=Path, help="folder of JSON results: each becomes metrics[file stem]"
    )
    parser.add_argument("--experiments", type=Path, help="JSON list of recipes tried")
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument("--out", type=Path, required=True, help="weights/MANIFEST.json")
    args = parser.parse_args(argv)
    metrics = json.loads(args.metrics.read_text()) if args.metrics else {}
    if args.metrics_dir is not None:
        metrics.update(collect_metrics(args.metrics_dir))
    experiments = json.loads(args.experiments.read_text()) if args.experiments else []
    manifest = build_manifest(
        args.out.parent,
        args.pretrain_run,
        args.head_run,
        metrics,
        experiments,
        args.data,
        native_head_run=args.native_head_run,
        pretrain_pairs=args.pretrain_pairs,
        pretrain_role=args.pretrain_role,
    )
    args.out.write_text(json.dumps(manifest, indent=2) + "\n")
    print(f"wrote {args.out} ({len(manifest['files'])} files hashed)")


if __name__ == "__main__":
    main()
