"""onnxruntime's side of `bino bench`: both sessions on one thread, the serve protocol."""

from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.ort_bench import (
    attends_within_rows,
    main,
    read_band,
    rows_as_batch,
    serve,
    sessions,
)

ENCODER = Path(__file__).resolve().parents[2] / "weights" / "bino_encoder.onnx"


@pytest.fixture()
def band(tmp_path: Path) -> Path:
    path = tmp_path / "band.pgm"
    pixels = np.random.default_rng(0).integers(0, 256, (48, 80), dtype=np.uint8)
    assert cv2.imwrite(str(path), pixels)
    return path


def test_the_int8_session_computes_what_the_float_one_does(band: Path) -> None:
    by_name = sessions(ENCODER)
    pixels = read_band(band)
    assert pixels.shape == (1, 3, 48, 80) and pixels.dtype == np.float32
    outputs = {}
    for name, session in by_name.items():
        options = session.get_session_options()
        assert options.intra_op_num_threads == 1 and options.inter_op_num_threads == 1
        feeds = {i.name: pixels for i in session.get_inputs()}
        outputs[name] = session.run(None, feeds)[0].reshape(-1, 128)
    f32, int8 = outputs["f32"], outputs["int8"]
    cosine = (f32 * int8).sum(1) / np.linalg.norm(f32, axis=1) / np.linalg.norm(int8, axis=1)
    # Dynamic quantisation perturbs the descriptors, it does not replace them.
    assert cosine.mean() > 0.9


def test_serve_answers_each_request_with_one_timing(band: Path) -> None:
    replies = io.StringIO()
    serve(ENCODER, band, io.StringIO("f32\nint8\nint8\n"), replies)
    lines = replies.getvalue().split()
    assert lines[0] == "ready"
    times = [float(x) for x in lines[1:]]
    assert len(times) == 3 and all(0 < t < 60 for t in times)


def test_serve_refuses_an_unknown_session(band: Path) -> None:
    with pytest.raises(SystemExit, match="unknown session 'fp16'"):
        serve(ENCODER, band, io.StringIO("fp16\n"), io.StringIO())


def test_runs_are_written_as_json(band: Path, tmp_path: Path) -> None:
    out = tmp_path / "ort.json"
    main(["--onnx", str(ENCODER), "--band", str(band), "--runs", "2", "--out", str(out)])
    report = json.loads(out.read_text())
    assert report["threads"] == 1 and (report["height"], report["width"]) == (48, 80)
    assert len(report["f32"]["runs_s"]) == len(report["int8_dynamic"]["runs_s"]) == 2


def test_an_unreadable_band_is_named(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="cannot read .*missing.pgm"):
        read_band(tmp_path / "missing.pgm")


def test_the_shipped_graph_runs_its_token_rows_as_a_batch_with_the_bands_outputs(
    band: Path,
) -> None:
    """Row attention and one row embedding: the band's token rows as a batch of one-row bands
    give the band's tokens, row for row."""
    assert attends_within_rows(ENCODER)
    pixels = read_band(band)
    rows = rows_as_batch(pixels)
    assert rows.shape == (12, 3, 4, 80)
    assert np.array_equal(rows[5, 1], pixels[0, 1, 20:24])
    session = sessions(ENCODER)["f32"]
    (whole,) = session.run(None, {"left": pixels, "right": pixels})
    (batched,) = session.run(None, {"left": rows, "right": rows})
    assert batched.shape == (12, 1, 40, 128)
    assert np.abs(batched[:, 0] - whole[0]).max() < 1e-4
