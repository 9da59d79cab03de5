"""Host speed tables: `bino bench` runs per CPU and ISA.
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
