"""Hostile and degenerate input files: one line and exit 2 (or a correct report), bounded memory.

Issue 24, items 5-7: the CLI's files (``--params``, a sweep's ``best.json``, session and event
files, camera images in a bag) are checked before anything large is allocated, and inputs that
are valid but degenerate (a map of one vertex) give a report, not a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.cli import main
from tests.test_dataset_reader import simple_bag
from tests.test_faults import one_line_error


def run_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """``cogmap ARGS`` must fail with exit code 2 and one line; return that line."""
    assert main(list(args)) == 2
    return one_line_error(capsys.readouterr().err)


# ------------------------------------------------------------------------ item 7: --params files
@pytest.fixture(scope="module")
def tiny_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simple_bag(tmp_path_factory.mktemp("bag") / "tiny.bag", n=12)


def test_params_nested_too_deep_is_one_line(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(deep)
    )
    assert line == (
        f"cogmap run: error: {deep}: not a readable JSON file (it is nested too deeply to read)"
    )
    assert not (tmp_path / "r").exists()


def test_params_integer_of_400_digits_is_one_line(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    big = tmp_path / "big.json"
    big.write_text('{"delta": 1' + "0" * 399 + "}")
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(big)
    )
    assert line == (
        f"cogmap run: error: {big}: delta=1" + "0" * 29 + "… (400 characters) is "
        "out of range: neighborhood field threshold (g > delta adds a vertex) must be in (1, 1e+12]"
    )


def test_params_true_is_not_a_number(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    flag = tmp_path / "flag.json"
    flag.write_text('{"alpha": true}')
    line = run_error(capsys, "serve", str(tiny_bag), "--params", str(flag))
    assert line == (
        f"cogmap serve: error: {flag}: alpha=True is not a number: weight of translation in the "
        "neighborhood field (1/m) must be in [0, 1e+06]"
    )


@pytest.mark.parametrize(
    ("entry", "value", "kind"),
    [
        ("", [1, 2], "list"),  # smallest_complete, the default entry
        ("#paper", "fast", "string"),
        ("#front_ate/0", 7, "number"),
    ],
)
def test_best_json_entries_of_the_wrong_type_are_one_line(
    tmp_path: Path, tiny_bag: Path, capsys, entry: str, value: object, kind: str
) -> None:
    best = tmp_path / "best.json"
    content = {"format": "cogmap-sweep-best", "smallest_complete": value, "paper": value}
    content["front_ate"] = [value]
    best.write_text(json.dumps(content))
    name = entry or "#smallest_complete"
    line = run_error(capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params",
                     f"{best}{entry}")  # fmt: skip
    assert line == (
        f"cogmap run: error: {best}{name}: the entry is a {kind}, not a setting (an object of "
        "parameters); the file is not a sweep's best.json as cogmap writes it"
    )
    best.write_text(json.dumps({"format": "cogmap-sweep-best", "front_ate": "none"}))
    line = run_error(capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params",
                     f"{best}#front_ate/0")  # fmt: skip
    assert line == (
        f"cogmap run: error: {best}#front_ate/0: front_ate is a string, not a list of settings; "
        "the file is not a sweep's best.json as cogmap writes it"
    )


def test_a_params_file_larger_than_16_mib_is_not_read(
    tmp_path: Path, tiny_bag: Path, capsys
) -> None:
    huge = tmp_path / "huge.json"
    with huge.open("wb") as handle:
        handle.truncate(17 * 1024 * 1024)  # sparse: nothing is written, nothing may be read
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(huge)
    )
    assert line == (
        f"cogmap run: error: {huge}: the parameter file has 17825792 bytes, more than the 16 MiB "
        "a parameter file may have"
    )


# ------------------------------------------------------------- item 6: valid input, tiny maps
def test_a_map_of_one_vertex_is_reported(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    """δ = 1000 keeps the compact map at one vertex: no ATE alignment, no correctness."""
    out = tmp_path / "r"
    assert main(["run", str(tiny_bag), "--out", str(out), "--delta", "1000"]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    compact = summary["maps"]["compact"]
    assert compact["vertices"] == 1 and compact["edges"] == 0
    assert compact["correctness"] is None
    assert (out / "map.png").stat().st_size > 0


def tuc_log(folder: Path, lines: int) -> Path:
    """A TUC log of ``lines`` odometry lines (0.1 m/s straight on) with its ground truth."""
    log = folder / "run_Input.txt"
    log.write_text("".join(f"odom2 {0.1 * k:.1f} 0.1 0.0 0.0 0 0 0\n" for k in range(lines)))
    (folder / "run_GT.txt").write_text(
        "".join(f"point2 {0.1 * k:.1f} {0.01 * k:.2f} 0.0 0 0 0 0\n" for k in range(lines))
    )
    return log


@pytest.mark.parametrize("lines", [2, 3])
def test_a_tuc_log_of_a_few_lines_with_ground_truth_is_reported(
    tmp_path: Path, capsys, lines: int
) -> None:
    log = tuc_log(tmp_path, lines)
    out = tmp_path / "r"
    assert main(["run", str(log), "--out", str(out)]) == 0
    assert "Traceback" not in capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == lines
    for entry in summary["maps"].values():
        assert entry["vertices"] == 1 and entry["ate_m"] == 0.0
        assert entry["completeness"] == 1.0 and entry["correctness"] is None
    assert (out / "map.png").stat().st_size > 0
