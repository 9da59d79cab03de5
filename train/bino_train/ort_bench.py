"""onnxruntime's timings of the encoder, for `bino bench` to put beside its own engines.

    python -m bino_train.ort_bench --onnx ../weights/bino_encoder.onnx --band band.pgm \
        --runs 20 --out ort.json
    python -m bino_train.ort_bench --onnx ../weights/bino_encoder.onnx --band band.pgm --serve

The band is the 8-bit gray image `bino bench` times its engines on; both ONNX inputs (left,
right) get it as float pixels p / 255, as tract does. Two sessions, each on one thread
(`intra_op_num_threads = inter_op_num_threads = 1`, sequential execution): the float graph,
and its dynamic int8 quantisation (`quantize_dynamic`, int8 weights, activations quantised at
run time), the usual way to run a float ONNX model in int8 on a CPU. Each gets one warm-up run
and then `--runs` timed runs of `session.run`; the JSON holds every run in seconds. A graph
that attends within each token row (`bino.config` attention_rows 0) runs the band's token rows
as a batch of one-row bands: the attention products the int8 engine computes, not the band's
masked all-pairs scores (the outputs are the same for the shipped encoder, whose every token row
has one row embedding).

`--serve` is how `bino bench` interleaves these runs with its own (so every engine sees the
same drift of a shared machine): after both warm-ups it prints `ready`, then answers each
line `f32` or `int8` on stdin with one timed run's seconds on stdout, until stdin closes.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, TextIO

import cv2
import numpy as np
import onnx as onnx_lib
import onnxruntime as ort
from numpy.typing import NDArray
from onnxruntime.quantization import QuantType, quantize_dynamic


def read_band(path: Path) -> NDArray[np.float32]:
    """The gray band as a (1, 3, H, W) float input, p / 255 in every channel."""
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        raise SystemExit(f"error: cannot read {path} as an 8-bit gray image")
    pixels = np.asarray(gray, dtype=np.float32) / np.float32(255.0)
    return np.ascontiguousarray(np.broadcast_to(pixels, (1, 3, *pixels.shape)))


def attends_within_rows(onnx: Path) -> bool:
    """Whether the graph holds attention to each token row (`bino.config`'s attention_rows 0)."""
    props = {p.key: p.value for p in onnx_lib.load(str(onnx)).metadata_props}
    return "'attention_rows': 0" in props.get("bino.config", "")


def rows_as_batch(band: NDArray[np.float32]) -> NDArray[np.float32]:
    """The (1, 3, H, W) band as a batch of its H / 4 token rows, (H / 4, 3, 4, W): under row
    attention each row attends within itself, so the batch computes the attention products
    the int8 engine does, where the band's graph computes every row's scores against the
    whole band and masks all but its own row's."""
    _, ch, h, w = band.shape
    if h % 4:
        raise SystemExit(f"error: band height {h} is not a multiple of 4")
    rows = band.reshape(ch, h // 4, 4, w).transpose(1, 0, 2, 3)
    return np.ascontiguousarray(rows)


def one_thread_session(model: Path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])


def time_session(
    session: ort.InferenceSession, band: NDArray[np.float32], runs: int
) -> list[float]:
    """One warm-up run, then `runs` timed runs; seconds each."""
    names = [i.name for i in session.get_inputs()]
    feeds = {name: band for name in names}
    session.run(None, feeds)
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        session.run(None, feeds)
        times.append(time.perf_counter() - started)
    return times


def sessions(onnx: Path) -> dict[str, ort.InferenceSession]:
    """The float session and its dynamic int8 quantisation, by name."""
    if not onnx.is_file():
        raise SystemExit(f"error: {onnx} does not exist")
    with tempfile.TemporaryDirectory() as tmp:
        quantised = Path(tmp) / "encoder_int8_dynamic.onnx"
        quantize_dynamic(str(onnx), str(quantised), weight_type=QuantType.QInt8)
        return {"f32": one_thread_session(onnx), "int8": one_thread_session(quantised)}


def bench_input(onnx: Path, band_path: Path) -> NDArray[np.float32]:
    """The band as the sessions run it: its token rows as a batch where the graph attends
    within each row (`rows_as_batch`), else the band."""
    band = read_band(band_path)
    return rows_as_batch(band) if attends_within_rows(onnx) else band


def serve(onnx: Path, band_path: Path, requests: TextIO, replies: TextIO) -> None:
    """Answer each request line (`f32` / `int8`) with one timed run in seconds."""
    band = bench_input(onnx, band_path)
    by_name = sessions(onnx)
    for session in by_name.values():
        time_session(session, band, 0)
    print("ready", file=replies, flush=True)
    for line in requests:
        name = line.strip()
        if name not in by_name:
            raise SystemExit(f"error: unknown session {name!r} (f32 or int8)")
        session = by_name[name]
        feeds = {i.name: band for i in session.get_inputs()}
        started = time.perf_counter()
        session.run(None, feeds)
        print(f"{time.perf_counter() - started:.9f}", file=replies, flush=True)


def bench(onnx: Path, band_path: Path, runs: int) -> dict[str, Any]:
    if runs < 1:
        raise SystemExit("error: --runs must be at least 1")
    band = bench_input(onnx, band_path)
    by_name = sessions(onnx)
    float_runs = time_session(by_name["f32"], band, runs)
    int8_runs = time_session(by_name["int8"], band, runs)
    return {
        "onnxruntime": ort.__version__,
        "threads": 1,
        "height": int(band.shape[0] * band.shape[2]),
        "width": int(band.shape[3]),
        "rows_as_batch": bool(band.shape[0] > 1),
        "f32": {"runs_s": float_runs},
        "int8_dynamic": {"runs_s": int8_runs},
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--onnx", type=Path, required=True, help="float encoder ONNX")
    parser.add_argument("--band", type=Path, required=True, help="8-bit gray band (PGM/PNG)")
    parser.add_argument("--runs", type=int, default=20, help="timed runs per session")
    parser.add_argument("--out", type=Path, help="JSON of every run")
    parser.add_argument("--serve", action="store_true", help="time runs asked for on stdin")
    args = parser.parse_args(argv)
    if args.serve:
        serve(args.onnx, args.band, sys.stdin, sys.stdout)
        return
    if args.out is None:
        parser.error("--out is needed unless --serve")
    report = bench(args.onnx, args.band, args.runs)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
