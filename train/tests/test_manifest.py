"""The manifest's pieces: artifact hashes and the metrics folder."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from bino_train.manifest import collect_metrics, file_hashes


def test_file_hashes_cover_artifacts_but_not_docs_or_the_manifest(tmp_path: Path) -> None:
    (tmp_path / "bino_int8.bin").write_bytes(b"\x00\x01blob")
    (tmp_path / "README.md").write_text("docs")
    (tmp_path / "MANIFEST.json").write_text("{}")
    (tmp_path / "sub").mkdir()
    hashes = file_hashes(tmp_path)
    assert hashes == {"bino_int8.bin": hashlib.sha256(b"\x00\x01blob").hexdigest()}


def test_collect_metrics_keys_each_json_by_its_stem(tmp_path: Path) -> None:
    (tmp_path / "probe_trained.json").write_text(json.dumps({"epe": 2.37}))
    (tmp_path / "benchmark_random.json").write_text(json.dumps({"hard_pck1": 40.5}))
    (tmp_path / "notes.txt").write_text("not a metric")
    metrics = collect_metrics(tmp_path)
    assert list(metrics) == ["benchmark_random", "probe_trained"]
    assert metrics["probe_trained"]["epe"] == 2.37


def test_collect_metrics_names_a_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="does not exist"):
        collect_metrics(tmp_path / "absent")


def test_collect_metrics_rejects_broken_json(tmp_path: Path) -> None:
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(SystemExit, match="broken.json is not valid JSON"):
        collect_metrics(tmp_path)
