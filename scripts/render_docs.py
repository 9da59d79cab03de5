#!/usr/bin/env python3
"""Renders every table of measured numbers in README.md and docs/*.md from the committed
measurement files, so each figure has one source.

    python3 scripts/render_docs.py            # rewrite the marked regions in place
    python3 scripts/render_docs.py --check    # exit 1 if a doc differs from a fresh render
    python3 scripts/render_docs.py --list     # the regions, their files and their sources
    python3 scripts/render_docs.py --self-test

A region is the text between `<!-- render:NAME -->` and `<!-- /render:NAME -->` on lines of
their own; NAME picks a renderer below. Sources: `train/checkpoints/metrics/*.json` (bino eval,
compare, bench, the Python probe and benchmark), `firmware-sim/measured/*.json` (the QEMU runs
and `bino budget`), `weights/MANIFEST.json` and the shipped files' sizes. Prose should quote a
rendered table rather than restate its figures. Python 3.11 standard library only.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import re
import sys
import tempfile
from collections.abc import Callable, Iterable, Sequence
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
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
"""The native pathway's learned readout (`bino run --pathway native`, the board's preset)."""
CENSUS_STAGES = ("native_rows", "native_sgm", "native_refine")
"""The firmware's measured native band pair stages that the census readout runs alone: the rows,
the census SGM (its codes, costs and SGM) and the refinement."""


def census_instructions(core: Json) -> int:
    """The census readout's instructions per 48x160 band pair on `core`: the measured native
    run's rows, census SGM and refinement stages (the same code on the same band)."""
    stages = {s["name"]: s["instructions"] for s in core["stages"]}
    return sum(stages[name] for name in CENSUS_STAGES)


# ---------------------------------------------------------------- accuracy


def accuracy_headline(src: Sources) -> str:
    rows = []
    for profile in ("w160", "w320"):
        ev, na = src.metrics(f"eval_{profile}"), src.metrics(f"native_{profile}")
        sgbm = metrics_of(ev["mean"]["sgbm"])
        census = metrics_of(ev["mean"][f"int8_{CENSUS}"])
        readouts = (
            ("`bino run`'s default, no encoder", CENSUS, ev),
            ("export pathway, learned", EXPORT_DEFAULT, ev),
            ("native pathway, learned, the board's", NATIVE_DEFAULT, na),
        )
        for label, readout, run in readouts:
            ours = metrics_of(run["mean"][f"int8_{readout}"])
            wins = [k for k in ("epe", "bad1tok", "bad2") if ours[k] < sgbm[k]]
            rows.append(
                [
                    f"{profile} ({ev['pairs']} eval pairs)",
                    f"int8 `{readout}` ({label})",
                    f3(ours["epe"]),
                    f2(ours["bad1tok"]),
                    f2(ours["bad2"]),
                    f"{ours['epe'] / census['epe']:.2f}x",
                    ", ".join(wins) if wins else "none",
                ]
            )
        rows.append(
            [
                f"{profile} ({ev['pairs']} eval pairs)",
                "StereoSGBM (OpenCV, same run)",
                f3(sgbm["epe"]),
                f2(sgbm["bad1tok"]),
                f2(sgbm["bad2"]),
                f"{sgbm['epe'] / census['epe']:.2f}x",
                "",
            ]
        )
    header = ["profile", "readout", "epe px", "bad1tok %", "bad2 %", "epe / census"]
    header += ["better than StereoSGBM on"]
    return table(header, rows, [False, False] + [True] * 4 + [False]) + "\n\n" + footer(src)


def eval_unrefined(src: Sources) -> str:
    evs = {p: src.metrics(f"eval_{p}") for p in ("w160", "w320")}
    rows = []
    for precision in ("f32", "int8"):
        for r in READOUTS:
            row = [f"{precision} `{r}`"]
            for p in ("w160", "w320"):
                e = evs[p]["mean"][f"{precision}_{r}"]
                m = metrics_of(e)
                row += [
                    f3(m["epe"]),
                    f2(m["bad1tok"]),
                    f2(m["bad2"]),
                    f"{e['lr_keep']:.1f}",
                    f3(e["gt_lr_epe"]),
                ]
            rows.append(row)
    row = ["StereoSGBM"]
    for p in ("w160", "w320"):
        m = metrics_of(evs[p]["mean"]["sgbm"])
        row += [f3(m["epe"]), f2(m["bad1tok"]), f2(m["bad2"]), f"density {m['density']:.1f}", "-"]
    rows.append(row)
    header = ["readout"]
    for p in ("w160", "w320"):
        header += [f"{p} epe", "bad1tok", "bad2", "LRkeep", "GT+LR epe"]
    return table(header, rows) + "\n\n" + footer(src)


def eval_refined(src: Sources) -> str:
    evs = {p: src.metrics(f"eval_{p}") for p in ("w160", "w320")}
    rows = []
    for precision in ("int8", "f32"):
        for r in READOUTS:
            row = [f"{precision} `{r}+ref`"]
            for p in ("w160", "w320"):
                raw = metrics_of(evs[p]["mean"][f"{precision}_{r}"])
                m = metrics_of(evs[p]["mean"][f"{precision}_{r}+ref"])
                change = 100.0 * (m["epe"] / raw["epe"] - 1.0)
                row += [f3(m["epe"]), f"{change:+.0f} %", f2(m["bad1tok"]), f2(m["bad2"])]
            rows.append(row)
    row = ["StereoSGBM"]
    for p in ("w160", "w320"):
        m = metrics_of(evs[p]["mean"]["sgbm"])
        row += [f3(m["epe"]), "", f2(m["bad1tok"]), f2(m["bad2"])]
    rows.append(row)
    header = ["readout"]
    for p in ("w160", "w320"):
        header += [f"{p} epe", "vs unrefined", "bad1tok", "bad2"]
    return table(header, rows) + "\n\n" + footer(src)


def probe_and_head(src: Sources) -> str:
    probe, rnd = src.metrics("probe_trained"), src.metrics("probe_random")
    head = src.metrics("head_eval_w160")
    cmp = src.metrics("int8_compare_w160")["mean"]
    rows = [
        ("no-linkage probe, trained encoder (float)", probe),
        ("no-linkage probe, the same architecture at random init (float)", rnd),
        ("shared head (float)", head["head"]),
        ("shared head with its own left-right check and fill, `head+lr` (float)", head["head+lr"]),
        ("no-linkage probe, int8 engine", cmp["int8"]),
        ("shared head, int8 engine", cmp["head"]["int8"]),
        (f"StereoSGBM (density {head['sgbm']['density']:.1f} %)", head["sgbm"]),
    ]
    body = [[name, f3(m["epe"]), f2(m["bad1tok"]), f2(m["bad2"])] for name, m in rows]
    return (
        table(["readout (w160, eval split)", "epe px", "bad1tok %", "bad2 %"], body)
        + "\n\n"
        + footer(src)
    )


def int8_vs_float(src: Sources) -> str:
    c = src.metrics("int8_compare_w160")
    m = c["mean"]
    shown = {
        "descriptor_cosine": ("descriptor cosine", lambda v: f"{v:.5f}"),
        "wta_agreement_pct": ("token WTA agreement", lambda v: pct(v, 2)),
        "epe_change_pct": ("no-linkage epe change, int8 over float", lambda v: f"{v:+.2f} %"),
    }
    rows = []
    for t in c["targets"]:
        label, fmt = shown.get(t["name"], (t["name"], lambda v: f"{v:g}"))
        rows.append([label, t["target"], fmt(t["value"]), "met" if t["pass"] else "**missed**"])
    rows += [
        [
            "shared head: epe change, int8 over float",
            "-",
            f"{m['head']['epe_change_pct']:+.2f} %",
            "",
        ],
        ["shared head: logit cosine", "-", f"{m['head']['logit_cosine']:.4f}", ""],
        ["native pathway: pair token cosine", "-", f"{m['native']['pair_token_cosine']:.5f}", ""],
        ["native head: logit cosine", "-", f"{m['native']['head']['logit_cosine']:.4f}", ""],
        [
            "native head: epe change, int8 over float",
            "-",
            f"{m['native']['head']['epe_change_pct']:+.2f} %",
            "",
        ],
        [
            "WTA flips: int8 winner's float-cosine loss / median best-to-second gap",
            "-",
            f"{m['wta_flip_loss']:.5f} / {m['wta_top2_gap']:.5f}",
            "",
        ],
    ]
    return (
        table(
            ["measure (w160, eval split)", "target", "measured", "state"],
            rows,
            [False, False, True, False],
        )
        + "\n\n"
        + footer(src)
    )


def pck_benchmark(src: Sources) -> str:
    t, r = src.metrics("benchmark_trained"), src.metrics("benchmark_random")
    rows = []
    for level in ("easy", "hard"):
        for name, d in (("trained", t), ("random init", r)):
            rows.append(
                [f"{level.upper()}, {name}"] + [f"{d[f'{level}_pck{k}']:.1f}" for k in (0, 1, 2)]
            )
    return table(["split, encoder", "PCK@0 %", "PCK@1 %", "PCK@2 %"], rows) + "\n\n" + footer(src)


# ---------------------------------------------------------------- robustness


def nuisance(profile: str, run: str = "eval_nuisance") -> Callable[[Sources], str]:
    """The nuisance table of `{run}_{profile}` (the export or the native pathway's run)."""

    def render(src: Sources) -> str:
        ev = src.metrics(f"{run}_{profile}")
        names = list(ev["nuisances"])
        rows = []
        for key in ev["mean"]:
            if key == "sgbm_large":
                continue
            label = "StereoSGBM" if key == "sgbm" else key.replace("_", " ", 1)
            row = [label, ep_b1(metrics_of(ev["mean"][key]))]
            for name in names:
                nu = ev["nuisances"][name]
                rise = nu["epe_rise"][key]
                star = " \\*" if nu.get("rise_below_sgbm", {}).get(key) else ""
                row.append(f"{ep_b1(metrics_of(nu['mean'][key]))} ({signed(rise)}{star})")
            rows.append(row)
        header = ["readout", "clean"] + names
        note = (
            f"{profile}, {ev['pairs']} eval pairs, epe px / bad1tok %, "
            "then the epe rise over clean; "
            "`*`: the rise is below StereoSGBM's."
        )
        return note + "\n\n" + table(header, rows, [False] * (len(header))) + "\n\n" + footer(src)

    return render


def occlusion_export(src: Sources) -> str:
    ev = src.metrics("occlusion_w160")
    summary = ev["occlusion"]["summary"]
    rows = []
    for key, s in summary.items():
        large = ev["mean"]["sgbm_large"] if key == "StereoSGBM" else ev["mean"][key]["large"]
        last = s["severities"][-1]
        label = key if key == "StereoSGBM" else key.replace("_", " ", 1)
        rows.append(
            [
                label,
                ep_b1(large),
                ep_b1(s["clean"]),
                ep_b1(last),
                f"{f3(s['auc_epe'])} / {f2(s['auc_bad1tok'])}",
                f"{signed(s['delta_epe'])} / {signed(s['delta_bad1tok'], 2)}",
            ]
        )
    top = ev["occlusion"]["severities"][-1]
    header = ["readout (w160)", "large-disparity subset", "clean", f"Occ{top}", "OccAUC", f"Δ{top}"]
    return table(header, rows, [False] * 6) + "\n\n" + footer(src)


# ---------------------------------------------------------------- native pathway


def native_vs_export(src: Sources) -> str:
    ex160, na160 = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_w320")
    exo, nao = src.metrics("occlusion_w160"), src.metrics("native_occlusion_w160")
    rows = []
    # Each head readout on both pathways, then each pathway's default (its head fused with its
    # second opinion: the descriptor SGM, the census SGM).
    pairs = [(f"int8 `{r}`", f"int8_{r}", f"int8_{r}") for r in ("head", "head+lr", "head+lr+ref")]
    pairs.append(
        (
            f"each learned default: int8 `{EXPORT_DEFAULT}` / `{NATIVE_DEFAULT}`",
            f"int8_{EXPORT_DEFAULT}",
            f"int8_{NATIVE_DEFAULT}",
        )
    )
    for label, k, kn in pairs:
        eo, no = exo["occlusion"]["summary"][k], nao["occlusion"]["summary"][kn]
        rows.append(
            [
                label,
                ep_b1(metrics_of(ex160["mean"][k])),
                ep_b1(metrics_of(na160["mean"][kn])),
                ep_b1(exo["mean"][k]["large"]),
                ep_b1(nao["mean"][kn]["large"]),
                f"{signed(eo['delta_epe'])} / {signed(eo['delta_bad1tok'], 2)}",
                f"{signed(no['delta_epe'])} / {signed(no['delta_bad1tok'], 2)}",
                ep_b1(metrics_of(ex320["mean"][k])),
                ep_b1(metrics_of(na320["mean"][kn])),
            ]
        )
    so = exo["occlusion"]["summary"]["StereoSGBM"]
    rows.append(
        [
            "StereoSGBM",
            ep_b1(metrics_of(ex160["mean"]["sgbm"])),
            "",
            ep_b1(exo["mean"]["sgbm_large"]),
            "",
            f"{signed(so['delta_epe'])} / {signed(so['delta_bad1tok'], 2)}",
            "",
            ep_b1(metrics_of(ex320["mean"]["sgbm"])),
            "",
        ]
    )
    top = exo["occlusion"]["severities"][-1]
    header = [
        "readout",
        "export w160",
        "native w160",
        "export large subset",
        "native large subset",
        f"export Δ{top}",
        f"native Δ{top}",
        "export w320",
        "native w320",
    ]
    note = "epe px / bad1tok %, eval split, the same blob for both pathways."
    return note + "\n\n" + table(header, rows, [False] * 9) + "\n\n" + footer(src)


def native_float(src: Sources) -> str:
    ex160, na160 = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_f32_w320")
    rows = []
    for r in ("head", "head+lr", "head+lr+ref"):
        k = f"f32_{r}"
        rows.append(
            [
                f"f32 `{r}`",
                ep_b1(metrics_of(ex160["mean"][k])),
                ep_b1(metrics_of(na160["mean"][k])),
                ep_b1(metrics_of(ex320["mean"][k])),
                ep_b1(metrics_of(na320["mean"][k])),
            ]
        )
    header = ["readout", "export w160", "native w160", "export w320", "native w320"]
    return table(header, rows, [False] * 5) + "\n\n" + footer(src)


# ---------------------------------------------------------------- host speed


def bench_rows(b: Json) -> list[tuple[str, Json]]:
    rows = [(f"int8 engine ({b['x86_kernels']} kernels)", b["int8"])]
    if "onnxruntime_int8_dynamic" in b:
        rows += [
            ("onnxruntime int8 (dynamic quantisation)", b["onnxruntime_int8_dynamic"]),
            ("onnxruntime f32", b["onnxruntime_f32"]),
        ]
    rows.append(("tract f32", b["tract_f32"]))
    return rows


BENCH_RUNS = ("bench_w160", "bench_w160_avx2", "bench_w160_xeon", "bench_w160_xeon_avx2")
"""`bino bench` runs, each CPU's VNNI run then its AVX2 one."""


def median_min(timing: Json) -> str:
    """A bench timing as "median (min min)"."""
    return f"{ms(timing['median_s'])} (min {ms(timing['min_s'])})"


def speed_headline(src: Sources) -> str:
    rows = []
    for run in (src.metrics(name) for name in BENCH_RUNS):
        ort = run.get("onnxruntime_int8_over_int8")
        rows.append(
            [
                f"{run['cpu']}, `{run['x86_kernels']}` kernels",
                median_min(run["int8"]),
                median_min(run["onnxruntime_int8_dynamic"]) if ort is not None else "-",
                ms(run["tract_f32"]["median_s"]),
                f"{ort:.2f}x" if ort is not None else "-",
                f"{run['tract_over_int8']:.2f}x",
            ]
        )
    header = [
        "host (one thread, one 48x160 band)",
        "int8 engine, median (min)",
        "onnxruntime int8, median (min)",
        "tract f32",
        "onnxruntime int8 / engine",
        "tract / engine",
    ]
    return table(header, rows) + "\n\n" + footer(src)


def bench_table(src: Sources) -> str:
    out = []
    for run in (src.metrics(name) for name in BENCH_RUNS):
        rows = [
            [name, ms(t["median_s"]), ms(t["min_s"]), f"{t['gmac_per_s']:.1f}"]
            for name, t in bench_rows(run)
        ]
        shipped = src.json(MANIFEST)["files"]["bino_int8.bin"]
        blob = (
            "the shipped blob"
            if run["blob_sha256"] == shipped
            else (f"blob sha256 `{run['blob_sha256'][:12]}…`, not the shipped `{shipped[:12]}…`")
        )
        title = (
            f"{run['cpu']}, `{run['x86_kernels']}` kernels, {len(run['int8']['runs_s'])} rounds, "
            f"{run['threads']} thread, {blob}:"
        )
        out.append(title + "\n\n" + table(["engine", "median", "min", "GMAC/s"], rows))
    return "\n\n".join(out) + "\n\n" + footer(src)


# ---------------------------------------------------------------- firmware


CORES = ("m55", "m7")


def core_label(c: Json) -> str:
    return f"Cortex-{c['cpu'].split('-')[1].upper()} ({c['board']})"


def board_headline(src: Sources) -> str:
    """Per core, the board's preset (the native pathway) and the export pathway: instructions of
    a 48x160 band pair, their time at IPC 1 and under the cycle model, the firmware's arena
    (one serves both runs) and blob."""
    rows = []
    for core in CORES:
        c = src.core(core)
        cm = c["cycle_model"]
        runs = (
            ("native (the board's preset)", c["native_band_pair_instructions"], cm["native_band_pair_modelled_ms"]),
            ("export", c["band_pair_instructions"], cm["band_pair_modelled_ms"]),
        )
        for pathway, ins, modelled_ms in runs:
            rows.append(
                [
                    f"{core_label(c)} at {c['clock_mhz']:.0f} MHz",
                    pathway,
                    mega(ins),
                    f"{ins / (c['clock_mhz'] * 1e3) / 1000:.2f} s",
                    f"{modelled_ms / 1000:.2f} s",
                    f"{n(c['arena_static_bytes'])} B",
                    f"{n(c['weights_flash_bytes'])} B",
                    "yes" if c["outputs_bit_identical"] else "**no**",
                ]
            )
    header = [
        "core (QEMU)",
        "pathway",
        "instructions per 48x160 band pair",
        "time at IPC 1",
        "cycle model",
        "arena",
        "weights flash",
        "bit-identical to the host",
    ]
    return table(header, rows) + "\n\n" + footer(src)


def board_pathways(src: Sources) -> str:
    """The board's readouts side by side: cost of a checked 48x160 band pair on each core and the
    accuracy of the refined readout on the eval split at w160 (the board's 160-px bands) and
    w320: the census alone (no encoder; its instructions the measured native run's rows, census
    SGM and refinement stages) and each pathway's learned default (the head fused with the
    descriptor SGM, or with the census SGM)."""
    ex, na = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_w320")
    pathways = (
        (
            "census, no encoder (`bino run`'s default): census SGM, its check, refinement",
            census_instructions,
            (ex, ex320),
            CENSUS,
        ),
        (
            "export: encode (L, L) and (R, R), SGM, census SGM, head, mirrored head",
            lambda c: c["band_pair_instructions"],
            (ex, ex320),
            EXPORT_DEFAULT,
        ),
        (
            "native (the board's preset): one encode on (L, R), native head, right view from its logits, census SGM",
            lambda c: c["native_band_pair_instructions"],
            (na, na320),
            NATIVE_DEFAULT,
        ),
    )
    rows = []
    for label, instructions, metrics, readout in pathways:
        row = [label, f"int8 `{readout}`"]
        row += [ep_b1(metrics_of(m["mean"][f"int8_{readout}"])) for m in metrics]
        for core in CORES:
            c = src.core(core)
            ins = instructions(c)
            row.append(f"{mega(ins)} ({ins / (c['clock_mhz'] * 1e6):.2f} s)")
        rows.append(row)
    header = ["readout, left-right check included", "readout", "eval w160 epe / bad1tok", "eval w320"]
    header += [f"{core.upper()} instructions (s at IPC 1)" for core in CORES]
    return table(header, rows) + "\n\n" + footer(src)


NATIVE_CHECKS = {
    "none": "no check",
    "mirrored": "second encoder pass on the mirrored pair",
    "diagonal": "right view from the logits' diagonal (one pass; shipped)",
    "confident0.5": "softmax peak >= 0.5",
}
FOLDER_TITLES = {
    "heldout": "held-out labeled",
    "synth": "synthetic",
    "synthreal": "synthetic, real textures",
}


def heldout_labeled(src: Sources) -> str:
    """The held-out labeled train pairs (validation): per pair, the readouts every recipe was
    chosen with against StereoSGBM, and how far the worst pair is from StereoSGBM's epe."""
    evs = {w: src.metrics(f"heldout_w{w}") for w in (160, 320)}
    natives = {w: src.metrics(f"native_heldout_w{w}") for w in (160, 320)}
    readouts = [CENSUS, "sgm+lr+ref", "head+lr+ref", "fuse+lr+ref", EXPORT_DEFAULT]
    rows = []
    pairs = [p["pair_id"] for p in evs[160]["per_pair"]]
    for i, pair in enumerate(pairs + ["mean"]):
        row = [f"`{pair}`" if pair != "mean" else "mean"]
        for w in (160, 320):
            ev = evs[w]
            got = ev["mean"] if pair == "mean" else ev["per_pair"][i]["readouts"]
            for r in readouts:
                row.append(ep_b1(metrics_of(got[f"int8_{r}"])))
            na = natives[w]
            native = na["mean"] if pair == "mean" else na["per_pair"][i]["readouts"]
            row.append(ep_b1(metrics_of(native[f"int8_{NATIVE_DEFAULT}"])))
            sgbm = metrics_of(got["sgbm"])
            census = metrics_of(got[f"int8_{CENSUS}"])
            learned = min(
                metrics_of(got[f"int8_{EXPORT_DEFAULT}"])["epe"],
                metrics_of(native[f"int8_{NATIVE_DEFAULT}"])["epe"],
            )
            row += [ep_b1(sgbm), f"{learned / census['epe']:.2f}"]
        rows.append(row)
    header = ["pair"]
    for w in (160, 320):
        header += [f"w{w} int8 `{r}`" for r in readouts]
        header += [f"w{w} native `{NATIVE_DEFAULT}` (the board's)"]
        header += [f"w{w} StereoSGBM", "best learned / census epe"]
    note = (
        "epe px / bad1tok %, int8, the held-out labeled train pairs no head was trained on "
        "(`bino_train.labeled.LABELED_HOLDOUT`: four MiddEval3-Q pairs and Middlebury 2006 "
        "Monopoly, resized by `bino_train.labeled_folder`), StereoSGBM in the same run; "
        "`scripts/measure_tables.sh heldout_w160 heldout_w320` (the native pathway's run: "
        "`native_heldout_w160`, `native_heldout_w320`). The last column: the better of the two "
        "learned defaults over `census+lr+ref`, below 1 where learning pays."
    )
    return note + "\n\n" + table(header, rows, [False] * len(header)) + "\n\n" + footer(src)


def mean_over(run: Json, key: str, pairs: Sequence[str]) -> Json:
    """The mean epe and bad1tok of `key` over `pairs` of an eval run's `per_pair`."""
    got = {p["pair_id"]: metrics_of(p["readouts"][key]) for p in run["per_pair"]}
    missing = [p for p in pairs if p not in got]
    if missing:
        raise SystemExit(f"{key}: no score for {', '.join(missing)}")
    return {m: sum(got[p][m] for p in pairs) / len(pairs) for m in ("epe", "bad1tok")}


REPRO = "train/checkpoints/repro_p7_short_blur/metrics"
"""The from-scratch reproduction's measurements (its own blob, the same commands)."""


def reproduction(src: Sources) -> str:
    """The weights `scripts/train_weights.sh` reproduced from scratch against the shipped ones:
    the encoder's probe and, int8, each pathway's default readout on the eval split and the
    held-out labeled pairs, StereoSGBM in the same runs."""

    def both(run: str, key: str) -> list[str]:
        """The shipped and the reproduced blob's mean of `key` in `run`, over the pairs the
        reproduction scored (the held-out set grew after it)."""
        shipped, repro = src.metrics(run), src.json(f"{REPRO}/{run}.json")
        if "per_pair" not in repro:
            got = (shipped["mean"][key], repro["mean"][key])
            return [ep_b1(metrics_of(g)) for g in got]
        pairs = [p["pair_id"] for p in repro["per_pair"]]
        return [ep_b1(mean_over(r, key, pairs)) for r in (shipped, repro)]

    probes = (src.metrics("probe_trained"), src.json(f"{REPRO}/probe_trained.json"))
    rows = [["no-linkage probe, eval w160 (float)", *(ep_b1(p) for p in probes)]]
    for label, prefix in (("eval split", "eval"), ("held-out labeled", "heldout")):
        for w in (160, 320):
            run, default = f"{prefix}_w{w}", EXPORT_DEFAULT
            rows.append([f"{label} w{w}, `{default}`", *both(run, f"int8_{default}")])
            if prefix == "heldout":
                native = both(f"native_{run}", f"int8_{NATIVE_DEFAULT}")
                rows.append([f"{label} w{w}, native `{NATIVE_DEFAULT}`", *native])
            rows.append([f"{label} w{w}, StereoSGBM", *both(run, "sgbm")])
    header = ["readout (int8 unless said)", "shipped weights", "reproduced from scratch"]
    note = "epe px / bad1tok %, each set scored by the same command on both blobs."
    return note + "\n\n" + table(header, rows, [False] * 3) + "\n\n" + footer(src)


def native_checks(src: Sources) -> str:
    """The native head's left-right checks on the validation folders (float, unrefined)."""
    data = src.json("train/checkpoints/metrics/native_checks.json")
    folders = list(data["folders"].items())
    rows = []
    for check, label in NATIVE_CHECKS.items():
        row = [label]
        for _, f in folders:
            m = f[check]["mean"]
            row.append(f"{ep_b1(m)} ({m['kept']:.0f} %)")
        rows.append(row)
    header = ["check"]
    for path, f in folders:
        kind = Path(path).name.rstrip("0123456789")
        header.append(f"{FOLDER_TITLES.get(kind, kind)} w{f['width']}")
    return table(header, rows, [False] * len(header)) + "\n\n" + footer(src)


def fw_memory(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    runs = {k: src.run(k) for k in CORES}
    spec: list[tuple[str, Callable[[str], str]]] = [
        (
            "weights flash (`.weights`: the blob, both heads)",
            lambda k: f"{n(cs[k]['weights_flash_bytes'])} B",
        ),
        (
            "code flash (`.vector_table .text .rodata .data`)",
            lambda k: f"{n(cs[k]['code_flash_bytes'])} B",
        ),
        (
            "arena, static / high-water, export pathway",
            lambda k: f"{n(cs[k]['arena_static_bytes'])} / {n(cs[k]['arena_high_water_bytes'])} B",
        ),
        ("arena high-water, native pathway", lambda k: f"{n(runs[k]['native']['arena_used'])} B"),
        ("of the arena: the refinement's state", lambda k: f"{n(cs[k]['refine_arena_bytes'])} B"),
        (
            "stack peak / reserved",
            lambda k: f"{n(cs[k]['stack_peak_bytes'])} / {n(cs[k]['stack_reserved_bytes'])} B",
        ),
        (
            "RAM reserved (`.data .bss .uninit` + stack)",
            lambda k: f"{n(cs[k]['ram_reserved_bytes'])} B",
        ),
        (
            "QEMU wall time of the run (both pathways)",
            lambda k: f"{cs[k]['qemu_wall_seconds']:.0f} s",
        ),
    ]
    rows = [[name] + [get(k) for k in CORES] for name, get in spec]
    return table(["memory"] + [core_label(cs[k]) for k in CORES], rows) + "\n\n" + footer(src)


STAGE_NOTES = {
    "load": "load (blob CRC and parse, once per pathway at boot)",
    "rows": "rows (camera rows from the interrupt into the band buffer)",
    "encode_left": "encode_left: encoder on (L, L)",
    "encode_right": "encode_right: encoder on (R, R)",
    "match": "match (inverse norms, cost row, WTA)",
    "sgm": "sgm (two streams)",
    "left_right": "left_right",
    "head": "head (the left head, then the mirrored head for its check, fused with the SGM rows)",
    "refine": "refine (pixel refinement of the fuse-all+lr grid, depth sectors)",
    "native_rows": "native_rows",
    "native_encode_pair": "native_encode_pair: one pass on (L, R)",
    "native_sgm": "native_sgm: the census SGM (census codes, cell costs, two streams)",
    "native_head": "native_head: the native head on the pair tokens, its check from its logits, fused with the census rows",
    "native_refine": "native_refine: pixel refinement of the fuse-census+lr grid, depth sectors",
}


def fw_stages(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    stages = {k: {s["name"]: s for s in cs[k]["stages"]} for k in CORES}
    names = sorted(
        (s["name"] for s in cs["m55"]["stages"]),
        key=lambda s: list(STAGE_NOTES).index(s) if s in STAGE_NOTES else len(STAGE_NOTES),
    )
    rows = []
    for name in names:
        row = [STAGE_NOTES.get(name, name), n(stages["m55"][name]["arena_in_use_bytes"])]
        for k in CORES:
            s = stages[k][name]
            row += [n(s["instructions"]), f"{s['estimated_ms']:,.1f}"]
        rows.append(row)

    def total(label: str, key: str, arena: str) -> list[str]:
        row = [f"**{label}**", arena]
        for k in CORES:
            c = cs[k]
            ins = c[key]
            row += [f"**{n(ins)}**", f"**{ins / (c['clock_mhz'] * 1e3):,.1f}**"]
        return row

    rows.append(
        total(
            "band pair, export pathway (all but load and native_*)",
            "band_pair_instructions",
            n(cs["m55"]["arena_high_water_bytes"]),
        )
    )
    rows.append(
        total(
            "band pair, native pathway with the head's check (all native_*)",
            "native_band_pair_instructions",
            n(src.run("m55")["native"]["arena_used"]),
        )
    )
    header = ["stage", "arena in use B"]
    for k in CORES:
        header += [
            f"{k.upper()} instructions",
            f"{k.upper()} ms at {cs[k]['clock_mhz']:.0f} MHz, IPC 1",
        ]
    return table(header, rows) + "\n\n" + footer(src)


# Instruction ceilings per export band pair that the kernels were tuned against; the budget file
# judges the time targets.
def fw_targets(src: Sources) -> str:
    b = src.budget()
    rows = [[t["target"], t["measured"], "met" if t["met"] else "**missed**"] for t in b["targets"]]
    return (
        table(["target", "measured", "state"], rows, [False, False, False]) + "\n\n" + footer(src)
    )


def fw_camera(src: Sources) -> str:
    cams = {k: src.run(k)["camera"] for k in CORES}
    cs = {k: src.core(k) for k in CORES}
    spec: list[tuple[str, Callable[[Json], str]]] = [
        ("band pair, export pathway, instructions", lambda c: n(c["band_pair_instructions"])),
        (
            "rows stage per row (interrupt included), instructions",
            lambda c: f"{c['rows_stage_instructions_per_row']:,.0f}",
        ),
        ("frames (48 rows, 160 px) per second", lambda c: f"{c['frames_per_s']:.3f}"),
        (
            "rows/s, framed sensor (blanked while the pipeline works)",
            lambda c: f"{c['framed_rows_per_s']:.2f}",
        ),
        (
            f"rows/s, sensor that never pauses ({cams['m55']['line_buffers']} line buffers)",
            lambda c: f"{c['continuous_rows_per_s']:.2f}",
        ),
        (
            "in-frame burst the rows stage drains, rows/s",
            lambda c: n(round(c["burst_rows_per_s"], -3)),
        ),
        ("rows delivered / lost in the run", lambda c: f"{c['delivered']} / {c['lost']}"),
    ]
    rows = [[name] + [get(cams[k]) for k in CORES] for name, get in spec]
    header = ["IPC-1 figures"] + [
        f"{core_label(cs[k]).split(' (')[0]} at {cs[k]['clock_mhz']:.0f} MHz" for k in CORES
    ]
    return table(header, rows) + "\n\n" + footer(src)


def fw_cycle_model(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    rows = []
    for stage in ("encode_left", "head"):
        row = [stage]
        for k in CORES:
            s = next(s for s in cs[k]["stages"] if s["name"] == stage)
            row += [
                f"{s['estimated_ms']:,.0f} ms",
                f"{mega(s['modelled_cycles'])} cycles, {s['modelled_ms']:,.0f} ms",
            ]
        rows.append(row)
    row = ["**band pair** (export pathway, all but load)"]
    for k in CORES:
        c, cm = cs[k], cs[k]["cycle_model"]
        per = cm["band_pair_modelled_cycles"] / c["band_pair_instructions"]
        row += [
            f"**{c['band_pair_estimated_ms']:,.0f} ms**",
            f"**{mega(cm['band_pair_modelled_cycles'])} cycles, "
            f"{cm['band_pair_modelled_ms']:,.0f} ms "
            f"({per:.2f} per instruction)**",
        ]
    rows.append(row)
    header = ["stage"]
    for k in CORES:
        header += [f"{k.upper()} IPC 1", f"{k.upper()} modelled"]
    return table(header, rows) + "\n\n" + footer(src)


# ---------------------------------------------------------------- weights


def weights_files(src: Sources) -> str:
    man = src.json(MANIFEST)
    rows = [
        [f"`{name}`", n(src.size(f"weights/{name}")), f"`{sha[:16]}…`"]
        for name, sha in man["files"].items()
    ]
    return (
        table(["file", "bytes", "sha256 (manifest)"], rows, [False, True, False])
        + "\n\n"
        + footer(src)
    )


def shipped_head(run: Json) -> str:
    """"last", or the interpolation `head_interpolate` made between two runs' heads."""
    mix = run.get("interpolated")
    if not mix:
        return "last"
    start, end = (Path(mix[k]).parent.name for k in ("start", "end"))
    return f"{mix['alpha']:g} of the way from `{start}` to `{end}` (weights)"


def training_summary(src: Sources) -> str:
    man = src.json(MANIFEST)
    pre, head, nat = man["pretraining"], man["head_training"], man["native_head_training"]
    hw = man["hardware"]
    rows = [
        [
            "encoder pretraining (self-supervised)",
            f"{n(pre['pairs_seen'])} pairs, {n(pre['steps'])} steps",
            f"{pre['train_seconds'] / 3600:.1f} h",
            f"`{pre['shipped_checkpoint']}`",
        ],
        [
            "shared head",
            f"{n(head['steps'])} steps",
            f"{head['train_seconds'] / 3600:.1f} h",
            shipped_head(head),
        ],
        ["native head", f"{n(nat['steps'])} steps", f"{nat['train_seconds'] / 3600:.1f} h", shipped_head(nat)],
    ]
    text = table(["model", "training", "time", "shipped"], rows, [False, False, True, False])
    text += (
        f"\n\nTraining pairs: {len(man['training_pairs'])} (the train split of `../shared/data`); "
        f"trained on {hw['cpu']}, {hw['torch_threads']} threads, "
        f"torch {hw['torch']}, CUDA {hw['cuda']}."
    )
    return text + "\n\n" + footer(src)


def blob_size(src: Sources) -> str:
    b = src.size("weights/bino_int8.bin")
    return (
        table(
            ["shipped int8 blob", "bytes", "MiB"],
            [
                [
                    "`weights/bino_int8.bin` (encoder, shared and native head)",
                    n(b),
                    f"{b / 2**20:.2f}",
                ]
            ],
        )
        + "\n\n"
        + footer(src)
    )


BOARDS = {"stm32h7": "STM32H743", "alif-e7": "Alif E7"}


def board_regions(src: Sources) -> str:
    rows = []
    notes = []
    for board, label in BOARDS.items():
        b = src.json(f"{MEASURED}/board-{board}.json")
        modified = " (engine or boards modified)" if b["core_or_boards_modified"] else ""
        notes.append(f"{label} at `{b['commit']}`{modified}")
        for i, r in enumerate(b["regions"]):
            sections = ", ".join(f"`{name}` {n(size)}" for name, size in r["sections"].items())
            if r["stack_above"] is not None:
                sections += f"; the stack gets the other {n(r['stack_above'])}"
            rows.append(
                [
                    label if i == 0 else "",
                    f"`{r['name']}`",
                    n(r["used"]),
                    n(r["size"]),
                    pct(100 * r["used"] / r["size"]),
                    sections,
                ]
            )
    header = ["board", "region", "used B", "size B", "use", "sections (B)"]
    text = table(header, rows, [False, False, True, True, True, False])
    return text + "\n\nBuilt from: " + "; ".join(notes) + ".\n\n" + footer(src)


def fps3(x: float) -> str:
    """Frames per second to three significant digits."""
    return f"{x:.3g}" if x >= 1 else f"{x:.{max(0, 2 - math.floor(math.log10(x)))}f}"


def fw_frames(src: Sources) -> str:
    b = src.budget()
    rows = []
    for e in b["frames"]["estimates"]:
        f = e["frame"]
        rows.append(
            [
                f"{f['width']}x{f['height']}",
                str(e["bands"]),
                f"{core_label(src.core(e['core'])).split(' (')[0]} at {e['clock_mhz']:.0f} MHz",
                e["pathway"],
                mega(e["instructions"]),
                f"{e['seconds_ipc1']:,.1f} s / {fps3(e['frames_per_s_ipc1'])}",
                f"{e['modelled_seconds']:,.1f} s / {fps3(e['modelled_frames_per_s'])}",
                mega(e["fitted_instructions"]),
                f"{n(e['arena_bytes'])} B",
            ]
        )
    header = [
        "frame (W x H)",
        "bands",
        "core",
        "pathway",
        "instructions",
        "IPC 1: s / fps",
        "cycle model: s / fps",
        "fitted through 48x32",
        "arena (exact)",
    ]
    right = [False, True, False, False, True, True, True, True, True]
    return table(header, rows, right) + "\n\n" + footer(src)


def fw_frame_check(src: Sources) -> str:
    checks = src.budget()["frames"]["scaling_check"]
    header = ["stage", "scaled by"]
    for c in checks:
        k = c["core"].upper()
        header += [f"{k} predicted", f"{k} measured", f"{k} error"]
    by = {
        "encoder": "encoder MACs per band",
        "pairs": "rows x candidate pairs",
        "cells": "rows x cells",
    }
    rows = []
    for i, s in enumerate(checks[0]["stages"]):
        name = s["name"] if s.get("scaling") else f"**{s['name']}**"
        row = [name, by.get(s.get("scaling", ""), "")]
        for c in checks:
            t = c["stages"][i]
            row += [n(t["predicted"]), n(t["measured"]), f"{t['error_percent']:+.1f} %"]
        rows.append(row)
    return table(header, rows, [False, False] + [True] * (len(header) - 2)) + "\n\n" + footer(src)


def census_vs_learned(src: Sources) -> str:
    """One sentence: where `census+lr+ref` is more accurate than both learned defaults (epe),
    where a learned one is, and what each costs on the board's M55 per 48x160 band pair."""
    # Each set's name, then the widths where the census or a learned readout has the lower epe.
    wins: dict[str, dict[bool, list[str]]] = {}

    def judge(name: str, width: str, census: float, learned: float) -> None:
        wins.setdefault(name, {True: [], False: []})[census <= learned].append(width)

    def learned_epe(export: Json, native: Json) -> float:
        return min(
            metrics_of(export[f"int8_{EXPORT_DEFAULT}"])["epe"],
            metrics_of(native[f"int8_{NATIVE_DEFAULT}"])["epe"],
        )

    for name, run in (("the eval split", "w"), ("the held-out real labeled pairs", "heldout_w")):
        for w in (160, 320):
            ex = src.metrics(f"eval_w{w}" if run == "w" else f"heldout_w{w}")
            na = src.metrics(f"native_w{w}" if run == "w" else f"native_heldout_w{w}")
            census = metrics_of(ex["mean"][f"int8_{CENSUS}"])["epe"]
            judge(name, f"w{w}", census, learned_epe(ex["mean"], na["mean"]))
    for w in (160, 320):
        ev, na = src.metrics(f"eval_nuisance_w{w}"), src.metrics(f"native_nuisance_w{w}")
        for name in ev["nuisances"]:
            means = ev["nuisances"][name]["mean"], na["nuisances"][name]["mean"]
            census = metrics_of(means[0][f"int8_{CENSUS}"])["epe"]
            judge(f"{name} nuisance", f"w{w}", census, learned_epe(*means))
    occ = src.metrics("occlusion_w160")["occlusion"]["summary"]
    native_occ = src.metrics("native_occlusion_w160")["occlusion"]["summary"]
    judge(
        "the one-view occlusion benchmark (OccAUC)",
        "w160",
        occ[f"int8_{CENSUS}"]["auc_epe"],
        min(occ[f"int8_{EXPORT_DEFAULT}"]["auc_epe"], native_occ[f"int8_{NATIVE_DEFAULT}"]["auc_epe"]),
    )

    def sets(census_better: bool) -> str:
        parts = [f"{name} ({', '.join(w[census_better])})" for name, w in wins.items() if w[census_better]]
        return ", ".join(parts) if parts else "none of them"

    m55 = src.core("m55")
    census_ins, native_ins = census_instructions(m55), m55["native_band_pair_instructions"]
    clock = m55["clock_mhz"] * 1e6
    return (
        f"`{CENSUS}` has a lower epe than both learned readouts (`{EXPORT_DEFAULT}`, "
        f"`{NATIVE_DEFAULT}`) on {sets(True)}; a learned readout is more accurate on "
        f"{sets(False)}. On the board's Cortex-M55 a 48x160 band pair costs {mega(census_ins)} "
        f"instructions with the census ({census_ins / clock:.2f} s at 400 MHz, IPC 1) against "
        f"{mega(native_ins)} ({native_ins / clock:.2f} s) for the learned native preset.\n\n"
        + footer(src)
    )


RENDERERS: dict[str, Callable[[Sources], str]] = {
    "census-vs-learned": census_vs_learned,
    "board-regions": board_regions,
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
    "native-checks": native_checks,
    "heldout-labeled": heldout_labeled,
    "reproduction": reproduction,
    "bench": bench_table,
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
    for path in documents(root):
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
