"""Host speed tables: `bino bench` runs per ISA, `bino run` timings per thread count.
"""

from __future__ import annotations

from .common import MANIFEST, Json, Sources, footer, ms, table

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


def all_cores_row(b: Json) -> list[str] | None:
    """The int8 engine on every core at once, per band, as a bench table row."""
    all_cores = b.get("int8_all_cores")
    if all_cores is None:
        return None
    rounds = all_cores["rounds"]
    per_band = 1 / all_cores["threads"]
    return [
        f"int8 engine, {all_cores['threads']} threads at once (per band)",
        ms(rounds["median_s"] * per_band),
        ms(rounds["min_s"] * per_band),
        f"{all_cores['gmac_per_s']:.1f}",
    ]


BENCH_RUNS = ("bench_w160", "bench_w160_avx2")
"""`bino bench` runs: the fastest kernels, then the same CPU held to its AVX2 kernels."""


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
                (all_cores_row(run) or ["", "-"])[1],
                f"{run['tract_over_int8']:.2f}x",
            ]
        )
    header = [
        "host (one thread, one 48x160 band)",
        "int8 engine, median (min)",
        "onnxruntime int8, median (min)",
        "tract f32",
        "onnxruntime int8 / engine",
        "engine on every core, per band",
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
        all_cores = all_cores_row(run)
        if all_cores is not None:
            rows.insert(1, all_cores)
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


RUN_TIMING = "run_timing_w320"
"""`scripts/measure_host.sh run`: `bino run` on one pair, per readout, build and threads."""

PATHWAY_READOUT = {
    "census": "census+lr+ref (no encoder)",
    "native": "native fuse-census+lr+ref",
    "export": "export fuse-all+lr+ref",
}


def run_timing(src: Sources) -> str:
    t = src.metrics(RUN_TIMING)
    runs = t["runs"]
    columns = list(dict.fromkeys((r["build"], r["threads"]) for r in runs))
    header = ["readout", "kernels"] + [
        f"{build}, {threads} thread{'s' if threads > 1 else ''}" for build, threads in columns
    ]
    rows = []
    for pathway, name in PATHWAY_READOUT.items():
        for kernels in dict.fromkeys(r.get("kernels", "fastest") for r in runs):
            cells = {
                (r["build"], r["threads"]): r
                for r in runs
                if r["readout_pathway"] == pathway and r.get("kernels", "fastest") == kernels
            }
            if not cells:
                continue
            row = [name, "-" if pathway == "census" else kernels]
            for key in columns:
                r = cells.get(key)
                row.append(f"{r['median_s']:.3f} s" if r else "")
            rows.append(row)
    title = (
        f"`bino run` on {t['pair']} at {t['profile']}, median of 10 runs (hyperfine -N), "
        f"{t['cpu']}, {t['cores']} cores, at commit {t['commit']}; `--kernels avx2` holds the "
        "engine to its AVX2 kernels (the census readout runs no encoder):"
    )
    return title + "\n\n" + table(header, rows, [False, False] + [True] * len(columns)) + "\n\n" + footer(src)
