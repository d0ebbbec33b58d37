"""The default dataset cache and the ``make-maze`` / ``dataset`` commands."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.cli import main
from cogmap_core.datasets import MazeConfig, cache
from cogmap_core.datasets.cache import (
    DATASET_VERSION,
    cache_dir,
    cached_bags,
    default_dataset_file,
    default_dataset_path,
)

LOOP = """\
; cell: 0.3
#########
#A.....B#
#.#####.#
#D.....C#
#########
"""


@pytest.fixture
def tiny_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A cache in tmp_path whose default dataset is a tiny, fast one."""
    layout = tmp_path / "loop.txt"
    layout.write_text(LOOP)
    monkeypatch.setenv("COGMAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(cache, "DEFAULT_CONFIG", MazeConfig(layout=str(layout), laps=1, fps=3.0))
    return tmp_path / "cache"


def test_cache_dir_from_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("COGMAP_CACHE", str(tmp_path / "c"))
    assert cache_dir() == tmp_path / "c"
    monkeypatch.delenv("COGMAP_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "cogmap"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_dir() == Path.home() / ".cache" / "cogmap"


def test_default_dataset_name_describes_it() -> None:
    assert default_dataset_file().name == f"irat_australia_6laps_seed1_v{DATASET_VERSION}.bag"


def test_default_dataset_is_generated_once_and_reused(
    tiny_default: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[int, int]] = []
    path = default_dataset_path(progress=lambda d, t: calls.append((d, t)))
    assert path.parent == tiny_default and path.exists()
    assert calls and calls[-1][0] == calls[-1][1]
    assert path.with_name(path.stem + "_maze.png").exists()
    assert sorted(p.name for p in tiny_default.iterdir() if not p.name.startswith(".")) == sorted(
        [
            path.name,
            path.stem + "_camera.png",
            path.stem + "_maze.png",
            path.stem + ".frontend.json",
        ]
    )

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("generated again")

    monkeypatch.setattr(cache, "generate_maze_bag", fail)
    assert default_dataset_path() == path
    assert [b.path for b in cached_bags()] == [path]
    assert cached_bags()[0].is_default


def test_regenerate_replaces_the_bag_and_cleans_partial_files(tiny_default: Path) -> None:
    path = default_dataset_path()
    before = path.read_bytes()
    stale = tiny_default / f".{path.name}.partial-999999"
    stale.write_bytes(b"half a bag")
    again = default_dataset_path(regenerate=True)
    assert again == path
    assert path.read_bytes() == before  # deterministic
    assert not stale.exists()


def test_unwritable_cache_is_a_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("COGMAP_CACHE", str(blocker / "cache"))
    assert main(["dataset", "path"]) == 2
    err = capsys.readouterr().err
    assert "cannot create the dataset cache" in err and "COGMAP_CACHE" in err
    assert err.count("\n") == 1


def test_dataset_commands(tiny_default: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["dataset", "list"]) == 0
    out = capsys.readouterr().out
    assert f"cache: {tiny_default}" in out and "not generated yet" in out
    assert "irat_australia: 3.7 x 2.5 m, waypoints ABCDEFGHIJ" in out

    assert main(["dataset", "path"]) == 0
    printed = capsys.readouterr().out.strip()
    assert Path(printed) == default_dataset_file() and Path(printed).exists()

    assert main(["dataset", "list"]) == 0
    assert "present" in capsys.readouterr().out

    assert main(["dataset", "info", printed, "--scan", "--image-scale", "2"]) == 0
    out = capsys.readouterr().out
    assert "ground truth: /overhead/pose (geometry_msgs/msg/PoseStamped)" in out
    assert "frames of 208x120 (scale 1/2)" in out
    assert "warning" not in out

    assert main(["dataset", "regenerate"]) == 0
    assert capsys.readouterr().out.strip() == printed


def test_make_maze_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    layout = tmp_path / "loop.txt"
    layout.write_text(LOOP)
    out = tmp_path / "run.bag"
    args = ["make-maze", str(out), "--layout", str(layout), "--laps", "1", "--fps", "3", "--quiet"]
    assert main([*args, "--preview", "--odom-noise", "0", "0", "--odom-bias", "0", "0", "0"]) == 0
    text = capsys.readouterr().out
    assert f"wrote {out}" in text
    assert "dead-reckoning error at the end: 0.00 m, 0.0 deg" in text
    assert (tmp_path / "run_camera.png").exists() and (tmp_path / "run_maze.png").exists()
    assert main(args) == 2
    assert "already exists" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0


@pytest.mark.parametrize("force", [False, True])
def test_make_maze_refuses_a_folder_as_out_before_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], force: bool
) -> None:
    layout = tmp_path / "loop.txt"
    layout.write_text(LOOP)
    folder = tmp_path / "run.bag"
    folder.mkdir()
    (folder / "mine.txt").write_text("mine")
    args = ["make-maze", str(folder), "--layout", str(layout), "--laps", "1", "--fps", "3"]
    assert main([*args, "--quiet", *(["--force"] if force else [])]) == 2
    assert capsys.readouterr().err == (
        f"cogmap make-maze: error: {folder} is a folder; give the path of the .bag file to write\n"
    )  # with --force it used to render the whole bag, then fail at the rename
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop.txt", "run.bag"]
    assert [p.name for p in folder.iterdir()] == ["mine.txt"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--speed", "5"], "speed 5.0 m/s is out of range"),
        (["--fps", "0"], "fps 0.0 is out of range"),
        (["--odom-noise", "-1", "0"], "odometry noise sigma_v=-1.0"),
        (["--odom-bias", "0", "0.9", "0"], "odometry bias bias_w=0.9"),
        (["--layout", "atlantis"], "no layout file or built-in layout named 'atlantis'"),
        (["--cell", "0"], "cell size 0.0 m is out of range"),
    ],
)
def test_make_maze_bad_arguments(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    assert main(["make-maze", str(tmp_path / "x.bag"), "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "x.bag").exists()


def test_partial_files_of_killed_generations_are_removed_on_next_use(tiny_default: Path) -> None:
    path = default_dataset_path()
    dead = tiny_default / f".{path.name}.partial-999999999"  # no such process
    dead.write_bytes(b"half a bag")
    live = tiny_default / f".{path.name}.partial-{os.getppid()}"  # a running process's
    live.write_bytes(b"being written")
    assert default_dataset_path() == path  # the bag exists: no generation, but clean-up
    assert not dead.exists() and live.exists()
