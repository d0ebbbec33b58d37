"""Usage errors of the ``cogmap`` command line: one line naming the command and its help."""

from __future__ import annotations

import pytest

from app.cli import main


def _usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``cogmap argv``, which must fail with exit 2; return its only stderr line."""
    try:
        code = main(argv)
    except SystemExit as stop:  # argparse's own errors exit
        code = stop.code
    assert code == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert captured.out == ""
    return lines[0]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (
            ["run", "x.bag", "--out", "o", "--no-such-option"],
            "cogmap run: error: unrecognized arguments: --no-such-option; see cogmap run --help",
        ),
        (
            ["run", "x.bag"],
            "cogmap run: error: the following arguments are required: --out; see cogmap run --help",
        ),
        (
            ["serve", "--speed", "fast"],
            "cogmap serve: error: argument --speed: speed 'fast' is not a number or 'max'; "
            "see cogmap serve --help",
        ),
        (
            ["frobnicate"],
            "cogmap: error: argument COMMAND: invalid choice: 'frobnicate' (choose from "
            "'serve', 'run', 'optimize', 'route', 'make-maze', 'make-log', 'dataset', 'sweep'); "
            "see cogmap --help",
        ),
        (
            ["--no-such-option"],
            "cogmap: error: unrecognized arguments: --no-such-option; see cogmap --help",
        ),
        (  # given before the sub-command: the top level's
            ["--bogus", "run", "x.bag", "--out", "o"],
            "cogmap: error: unrecognized arguments: --bogus; see cogmap --help",
        ),
    ],
)
def test_usage_errors_are_one_line_with_the_command_and_its_help(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _usage_error(argv, capsys) == expected


def test_help_still_prints_the_usage(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["run", "--help"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith("usage: cogmap run ")
