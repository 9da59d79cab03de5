"""The validation sets' tools: the folder writers' errors, and the table of `bino eval --json`
files of several sets with ratios to a baseline."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from bino_train.validation_table import geometric_mean, load_run, main, render


def _write(folder: Path, name: str, scores: dict[str, tuple[float, float]]) -> None:
    """A `bino eval --json` file's `mean` block (and a non-readout entry, as the CLI writes)."""
    mean: dict[str, object] = {
        readout: {"metrics": {"epe": epe, "bad1tok": bad, "bad2": 0.0, "density": 100.0}}
        for readout, (epe, bad) in scores.items()
    }
    mean["sgbm_note"] = "not a readout"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.json").write_text(json.dumps({"mean": mean}))


def test_ratios_and_their_geometric_mean_follow_the_baseline(tmp_path: Path) -> None:
    base, run = tmp_path / "base", tmp_path / "run"
    _write(base, "heldout160", {"int8_fuse+lr+ref": (1.0, 4.0)})
    _write(base, "synth320", {"int8_fuse+lr+ref": (2.0, 8.0)})
    _write(run, "heldout160", {"int8_fuse+lr+ref": (0.5, 2.0), "int8_sgm+lr+ref": (0.9, 5.0)})
    _write(run, "synth320", {"int8_fuse+lr+ref": (4.0, 9.0)})
    table = render(load_run(run), load_run(base)).splitlines()
    assert table[0] == "| readout | heldout w160 | synth w320 | epe / baseline (geo. mean) |"
    fuse = next(line for line in table if line.startswith("| int8_fuse+lr+ref"))
    # Ratios 0.5 and 2.0: geometric mean 1.
    assert "0.500 / 2.00 (0.500)" in fuse and "4.000 / 9.00 (2.000)" in fuse
    assert fuse.endswith("| 1.0000 |")
    # A readout the baseline lacks gets scores but no ratio; one a set lacks gets "-".
    sgm = next(line for line in table if line.startswith("| int8_sgm+lr+ref"))
    assert sgm == "| int8_sgm+lr+ref | 0.900 / 5.00 | - | - |"


def test_geometric_mean() -> None:
    assert geometric_mean([2.0, 8.0]) == pytest.approx(4.0)


def test_an_empty_folder_and_a_foreign_json_are_named_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit, match="no validation results"):
        main([str(tmp_path)])
    (tmp_path / "real160.json").write_text('{"other": 1}')
    with pytest.raises(SystemExit, match=r"real160\.json: not a bino eval --json file"):
        main([str(tmp_path)])
    _write(tmp_path, "real160", {"int8_head": (1.25, 3.0)})
    main([str(tmp_path)])
    assert "| int8_head | 1.250 / 3.00 |" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("module", "extra"),
    [("labeled_folder", []), ("val_folder", []), ("synth_folder", ["--textures", "real"])],
)
def test_folder_writers_name_a_missing_index_in_one_line(
    tmp_path: Path, module: str, extra: list[str]
) -> None:
    main_of = importlib.import_module(f"bino_train.{module}").main
    missing = tmp_path / "no-data"
    args = ["--out", str(tmp_path / "out"), "--width", "160", "--data", str(missing), *extra]
    with pytest.raises(SystemExit, match=rf"^error: {module}: no PAIRS\.tsv in .*no-data$"):
        main_of(args)
