"""The renderers' shared pieces: where the measurement files are, the `Sources` they are read
through, table formatting, and the readouts every accuracy table names.
"""

from __future__ import annotations

import math

import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
"""The repository: `scripts/rendering/common.py` is two folders below it."""
METRICS = "train/checkpoints/metrics"
MEASURED = "firmware-sim/measured"
MANIFEST = "weights/MANIFEST.json"

Json = dict[str, Any]
# The README is the front door: what the project is, a quickstart and the headline figures;
# everything else lives in docs/.
README_MAX_LINES = 250
MARK = re.compile(
    r"^<!-- render:([a-z0-9-]+) -->$\n(.*?)^<!-- /render:\1 -->$", re.MULTILINE | re.DOTALL
)
OPEN = re.compile(r"^<!-- render:([a-z0-9-]+) -->$", re.MULTILINE)


class Sources:
    """Reads measurement files below a root, remembering which ones a renderer used."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.used: list[str] = []
        self._cache: dict[str, Json] = {}

    def json(self, rel: str) -> Json:
        if rel not in self.used:
            self.used.append(rel)
        if rel not in self._cache:
            path = self.root / rel
            try:
                self._cache[rel] = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as e:
                raise SystemExit(f"{rel}: cannot read measurement file ({e})") from e
        return self._cache[rel]

    def size(self, rel: str) -> int:
        if rel not in self.used:
            self.used.append(rel)
        return (self.root / rel).stat().st_size

    def metrics(self, name: str) -> Json:
        return self.json(f"{METRICS}/{name}.json")

    def budget(self) -> Json:
        return self.json(f"{MEASURED}/budget.json")

    def run(self, core: str) -> Json:
        return self.json(f"{MEASURED}/{core}.json")

    def core(self, core: str) -> Json:
        for c in self.budget()["cores"]:
            if c["core"] == core:
                return dict(c)
        raise SystemExit(f"{MEASURED}/budget.json: no core {core}")


# ---------------------------------------------------------------- formatting


def table(
    header: Sequence[str], rows: Iterable[Sequence[str]], right: Sequence[bool] | None = None
) -> str:
    align = right if right is not None else [False] + [True] * (len(header) - 1)
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" if r else "---" for r in align) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def f3(x: float) -> str:
    return f"{x:.3f}"


def f2(x: float) -> str:
    return f"{x:.2f}"


def signed(x: float, digits: int = 3) -> str:
    return f"{x:+.{digits}f}"


def n(x: float) -> str:
    return f"{round(x):,}"


def fps3(x: float) -> str:
    """Frames per second to three significant digits."""
    return f"{x:.3g}" if x >= 1 else f"{x:.{max(0, 2 - math.floor(math.log10(x)))}f}"


def mega(x: float) -> str:
    return f"{x / 1e6:,.1f}M"


def ms(seconds: float) -> str:
    return f"{seconds * 1000:.1f} ms"


def pct(x: float, digits: int = 1) -> str:
    return f"{x:.{digits}f} %"


def ep_b1(m: Json) -> str:
    return f"{f3(m['epe'])} / {f2(m['bad1tok'])}"


def footer(src: Sources) -> str:
    return (
        "Rendered by `scripts/render_docs.py` from " + ", ".join(f"`{s}`" for s in src.used) + "."
    )


def metrics_of(entry: Json) -> Json:
    """An eval `mean` entry: readouts hold `metrics`, StereoSGBM holds the metrics itself."""
    return dict(entry["metrics"]) if "metrics" in entry else entry


READOUTS = [
    "census",
    "census+lr",
    "nolink",
    "nolink+lr",
    "sgm",
    "sgm+lr",
    "head",
    "head+lr",
    "fuse",
    "fuse+lr",
]
CENSUS = "census+lr+ref"
"""The census SGM with its check, refined: no encoder; the baseline every learned readout must beat."""
DEFAULT = {"w160": CENSUS, "w320": CENSUS}
"""`bino run`'s default readout (`pathway::DEFAULT_READOUT`, refined) at each profile."""
EXPORT_DEFAULT = "fuse-all+lr+ref"
"""The export pathway's learned readout (`bino run --pathway export`)."""
NATIVE_DEFAULT = "fuse-census+lr+ref"
"""The native pathway's learned readout (`bino run --pathway native`, the board's learned preset)."""
CENSUS_STAGES = ("native_rows", "native_sgm", "native_refine")
"""The firmware's measured native band pair stages that the census readout runs alone: the rows,
the census SGM (its codes, costs and SGM) and the refinement."""


def census_instructions(core: Json) -> int:
    """The census readout's instructions per 48x160 band pair on `core`: the measured native
    run's rows, census SGM and refinement stages (the same code on the same band)."""
    stages = {s["name"]: s["instructions"] for s in core["stages"]}
    return sum(stages[name] for name in CENSUS_STAGES)
