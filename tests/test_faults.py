"""Faults around ``cogmap run``'s report folder: --force, interruption, read-only and full disks.

Nothing written earlier may be lost and no half report may look complete: every case checks
the exit code, the one-line message and exactly what is left on disk.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from app.cli import main
from app.report import MARKER
from cogmap_core.errors import OutputError
from cogmap_core.g2o import write_g2o
from tests.test_dataset_reader import simple_bag
from tests.test_g2o import small_graph

ROOT = Path(__file__).resolve().parents[1]
#: A report's files in the order the marker lists them (the marker itself is written last).
REPORT_ORDER = (
    "config.json",
    "summary.json",
    "sizes.csv",
    "standard.g2o",
    "scene_integration.g2o",
    "compact.g2o",
    "trajectory_tum.txt",
    "groundtruth_tum.txt",
    "size.png",
    "size.svg",
    "map.png",
    "map.svg",
)
REPORT = {MARKER, *REPORT_ORDER}


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simple_bag(tmp_path_factory.mktemp("fault-bag") / "tiny.bag", n=60)


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry below ``folder``: relative path -> bytes (None for a folder)."""
    out: dict[str, bytes | None] = {}
    for path in sorted(folder.rglob("*")):
        rel = str(path.relative_to(folder))
        out[rel] = None if path.is_dir() else path.read_bytes()
    return out


def one_line_error(err: str) -> str:
    """The error line printed by the command (after any progress-bar output)."""
    lines = [line for line in err.replace("\r", "\n").splitlines() if "error:" in line]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def corrupt_mid_bag(bag: Path, out: Path) -> Path:
    """A copy of ``bag`` whose middle message record has an unknown record type."""
    data = bytearray(bag.read_bytes())
    records = [i for i in range(len(data) - 4) if data[i : i + 4] == b"op=\x02"]
    data[records[len(records) // 2] + 3] = 0x09
    out.write_bytes(bytes(data))
    return out


def old_report(bag: Path, out: Path) -> dict[str, bytes | None]:
    assert main(["run", str(bag), "--out", str(out), "--delta", "5"]) == 0
    return snapshot(out)


# ------------------------------------------------------------------------------------ --force
def test_force_replaces_only_the_report_files(bag: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "input.bag").write_bytes(bag.read_bytes())
    (out / "notes.txt").write_text("mine")
    (out / "sub").mkdir()
    (out / "sub" / "summary.json").write_text("not ours either")
    before = snapshot(out)
    assert main(["run", str(bag), "--out", str(out)]) == 2  # not empty, no --force
    assert "--force" in one_line_error(capsys.readouterr().err)
    assert snapshot(out) == before
    assert main(["run", str(bag), "--out", str(out), "--force"]) == 0
    after = snapshot(out)
    for name, content in before.items():  # nothing of the user's was touched
        assert after[name] == content, name
    assert set(after) == set(before) | REPORT
    marker = json.loads((out / MARKER).read_text())
    assert set(marker["files"]) == REPORT - {MARKER}
    assert marker["files"] == list(REPORT_ORDER)


def test_force_into_the_working_directory_keeps_everything_else(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    (work / "input.bag").write_bytes(bag.read_bytes())
    (work / "src").mkdir()
    (work / "src" / "a.py").write_text("print(1)\n")
    before = snapshot(work)
    monkeypatch.chdir(work)
    assert main(["run", "input.bag", "--out", ".", "--force"]) == 0
    after = snapshot(work)
    assert {k: after[k] for k in before} == before
    assert set(after) == set(before) | REPORT


def test_force_over_an_old_report_drops_only_its_stale_files(bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    old = old_report(bag, out)
    (out / "notes.txt").write_text("mine")
    assert main(["run", str(bag), "--out", str(out), "--force", "--no-ground-truth"]) == 0
    after = snapshot(out)
    assert "groundtruth_tum.txt" not in after  # the old report's, not written this time
    assert after["notes.txt"] == b"mine"
    assert after["summary.json"] != old["summary.json"]
    assert set(after) == REPORT - {"groundtruth_tum.txt"} | {"notes.txt"}
    assert json.loads(after[MARKER])["files"] == [  # type: ignore[arg-type]
        name for name in REPORT_ORDER if name != "groundtruth_tum.txt"
    ]


def test_force_never_deletes_a_file_the_marker_names_that_is_not_a_report_file(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    old_report(bag, out)
    (out / "precious.txt").write_text("mine")
    marker = json.loads((out / MARKER).read_text())
    marker["files"].append("precious.txt")  # a hand-edited or foreign marker
    (out / MARKER).write_text(json.dumps(marker))
    assert main(["run", str(bag), "--out", str(out), "--force"]) == 0
    assert (out / "precious.txt").read_text() == "mine"
    assert "precious.txt" not in json.loads((out / MARKER).read_text())["files"]


def test_a_folder_named_like_a_report_file_is_refused_before_any_work(
    bag: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "out"
    (out / "map.png").mkdir(parents=True)
    assert main(["run", str(bag), "--out", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'map.png'} is a folder" in one_line_error(err)
    assert "frames" not in err  # refused before processing
    assert snapshot(out) == {"map.png": None}


# ---------------------------------------------------------------------- failures and interrupts
def test_a_corrupt_bag_leaves_the_old_report_intact(bag: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    old = old_report(bag, out)
    broken = corrupt_mid_bag(bag, tmp_path / "broken.bag")
    capsys.readouterr()
    assert main(["run", str(broken), "--out", str(out), "--force"]) == 2
    assert "is corrupt near t=" in one_line_error(capsys.readouterr().err)
    assert snapshot(out) == old  # no staging folder left either


def test_ctrl_c_while_processing_leaves_nothing(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    from cogmap_core.slam import SlamSession

    original = SlamSession.process

    def interrupted(self: SlamSession, frame: object) -> object:
        if frame.index == 30:  # type: ignore[attr-defined]
            raise KeyboardInterrupt
        return original(self, frame)  # type: ignore[arg-type]

    monkeypatch.setattr(SlamSession, "process", interrupted)
    out = tmp_path / "deep" / "er" / "out"
    assert main(["run", str(bag), "--out", str(out)]) == 130
    assert capsys.readouterr().err.rstrip().endswith("cogmap run: interrupted")
    assert list(tmp_path.iterdir()) == []  # not even the parent folders it made


def _run_paused_in_the_write_phase(bag: Path, out: Path, extra: list[str]) -> subprocess.Popen:
    """``cogmap run`` in a subprocess whose g2o writer stalls after writing the first map."""
    script = (
        "import signal, sys, time\n"
        # a shell's background job starts with Ctrl-C ignored, and Python keeps it ignored
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "import app.pipeline as p\n"
        "real = p.write_g2o\n"
        "def slow(graph, path):\n"
        "    real(graph, path)\n"
        "    print('wrote', path, file=sys.stderr, flush=True)\n"
        "    time.sleep(60)\n"
        "p.write_g2o = slow\n"
        "from app.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.Popen(
        [sys.executable, "-c", script, "run", str(bag), "--out", str(out), *extra],
        cwd=ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_line(proc: subprocess.Popen, prefix: str) -> list[str]:
    seen: list[str] = []
    assert proc.stderr is not None
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if line.replace("\r", "\n").splitlines()[-1].startswith(prefix):
            return seen
    proc.kill()
    raise AssertionError(f"never saw {prefix!r}: {seen}")


@pytest.mark.parametrize(
    ("sig", "code", "said"),
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
    ids=["SIGINT", "SIGTERM"],
)
@pytest.mark.parametrize("existing", [False, True], ids=["new-folder", "old-report"])
def test_a_signal_in_the_write_phase_keeps_the_old_report(
    bag: Path, tmp_path: Path, existing: bool, sig: signal.Signals, code: int, said: str
) -> None:
    """Ctrl-C or a polite kill while the report is staged: a clean exit, nothing half written."""
    out = tmp_path / "out"
    old = old_report(bag, out) if existing else None
    proc = _run_paused_in_the_write_phase(bag, out, ["--force"] if existing else [])
    try:
        _wait_for_line(proc, "cogmap run: writing the report to")
        _wait_for_line(proc, "wrote ")  # config, summary, sizes and one map are staged
        staging = [p for p in tmp_path.rglob("*.partial-*") if p.is_dir()]
        assert len(staging) == 1 and (staging[0] / "summary.json").is_file()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code
    assert err.rstrip().endswith(f"cogmap run: {said}")
    assert "Traceback" not in err and "stack trace" not in err  # (glog's crash report)
    assert "SIGTERM" not in err and sig.name not in err
    if old is None:
        assert list(tmp_path.iterdir()) == []  # not even the folder it made
    else:
        assert snapshot(out) == old
        assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_a_killed_run_leaves_a_staging_folder_the_next_run_removes(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    proc = _run_paused_in_the_write_phase(bag, out, [])
    try:
        _wait_for_line(proc, "wrote ")
        proc.kill()  # SIGKILL: no clean-up possible
        proc.wait(timeout=30)
    finally:
        proc.kill()
    (leftover,) = tmp_path.iterdir()
    assert leftover.name == f".out.partial-{proc.pid}" and not out.exists()
    live = tmp_path / f".out.partial-{os.getppid()}"  # a running process's: left alone
    live.mkdir()
    assert main(["run", str(bag), "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, "out"]
    assert set(snapshot(out)) == REPORT


# -------------------------------------------------------------------- read-only and full disks
@pytest.fixture
def mount_point(tmp_path: Path) -> Iterator[Path]:
    """A folder to mount a tmpfs on (unmounted afterwards)."""
    folder = tmp_path / "mnt"
    folder.mkdir()
    yield folder
    subprocess.run(["umount", str(folder)], capture_output=True, check=False)


def _mount(folder: Path, options: str) -> None:
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or 'not root'})")


def test_read_only_folder_is_refused_before_processing(
    bag: Path, mount_point: Path, capsys
) -> None:
    _mount(mount_point, "ro,size=64k")
    for out in (mount_point, mount_point / "report"):
        assert main(["run", str(bag), "--out", str(out), "--force"]) == 2
        err = capsys.readouterr().err
        assert one_line_error(err) == (
            f"cogmap run: error: cannot write in {mount_point}: Read-only file system "
            "(the file system is read-only; write somewhere else)"
        )
        assert "frames" not in err  # no progress bar: the bag was not processed
    assert list(mount_point.iterdir()) == []


def test_read_only_folder_faked(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    def refuse(self: Path, *args: object, **kwargs: object) -> None:
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    assert main(["run", str(bag), "--out", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert "cannot write in" in one_line_error(err) and "read-only" in err
    assert "frames" not in err
    assert list(tmp_path.iterdir()) == []


def test_full_disk_leaves_nothing_half_written(bag: Path, mount_point: Path, capsys) -> None:
    _mount(mount_point, "size=64k")
    out = mount_point / "report"
    assert main(["run", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert one_line_error(err) == (
        f"cogmap run: error: cannot write the report {out}: No space left on device (the disk "
        "is full; free some space or write somewhere else); nothing was written"
    )
    assert "writing the report" in err  # the failure came while writing
    assert list(mount_point.iterdir()) == []


def test_full_disk_faked_keeps_the_old_report(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    out = tmp_path / "out"
    old = old_report(bag, out)
    import app.pipeline

    def full(figure: object, path: Path) -> list[Path]:
        path.write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(app.pipeline, "save_figure", full)
    capsys.readouterr()
    assert main(["run", str(bag), "--out", str(out), "--force"]) == 2
    assert "No space left on device" in one_line_error(capsys.readouterr().err)
    assert snapshot(out) == old


def test_full_disk_while_saving_the_session_is_one_line_and_keeps_the_old_session(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    import numpy as np

    session = tmp_path / "maze.session.npz"
    session.write_bytes(b"yesterday's session")

    def full(handle: object, **arrays: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full)
    args = ["run", str(bag), "--out", str(tmp_path / "out"), "--save-session", str(session)]
    assert main([*args, "--force"]) == 2
    assert one_line_error(capsys.readouterr().err) == (
        f"cogmap run: error: cannot write {session}: No space left on device (the disk is full; "
        "free some space or write somewhere else)"
    )
    assert session.read_bytes() == b"yesterday's session"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maze.session.npz"]


# ------------------------------------------------------------------------- other outputs
def test_written_files_get_the_users_normal_permissions(bag: Path, tmp_path: Path) -> None:
    umask = os.umask(0o022)
    try:
        write_g2o(small_graph(), tmp_path / "g.g2o")
        assert main(["run", str(bag), "--out", str(tmp_path / "out")]) == 0
    finally:
        os.umask(umask)
    assert (tmp_path / "g.g2o").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o755
    for path in (tmp_path / "out").iterdir():
        assert path.stat().st_mode & 0o777 == 0o644, path.name


def test_a_killed_writers_temporary_file_is_removed_by_the_next_write(tmp_path: Path) -> None:
    finished = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    dead = tmp_path / f".g.g2o.partial-{int(finished.stdout)}.0a1b2c3d"
    dead.write_text("half a graph from a killed run")
    running = tmp_path / f".g.g2o.partial-{os.getpid()}.deadbeef"  # a writer still at work
    running.write_text("being written")
    mine = tmp_path / f".other.g2o.partial-{int(finished.stdout)}.00000000"  # not this file's
    mine.write_text("another file's leftover")
    write_g2o(small_graph(), tmp_path / "g.g2o")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["g.g2o", running.name, mine.name])


def test_optimize_checks_the_output_folder_before_optimising(
    tmp_path: Path, data_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    import app.cmd_optimize

    out = tmp_path / "out.g2o"
    out.write_text("old result\n")

    def no_space(graph: object, path: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(app.cmd_optimize, "write_g2o", no_space)
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(out)]) == 2
    line = one_line_error(capsys.readouterr().err)
    assert line == (
        f"cogmap optimize: error: cannot write {out}: No space left on device (the disk is "
        "full; free some space or write somewhere else)"
    )
    assert out.read_text() == "old result\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.g2o"]

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("optimised although the output cannot be written")

    def read_only(folder: Path) -> None:
        raise OutputError(f"cannot write in {folder}: Read-only file system")

    monkeypatch.setattr(app.cmd_optimize, "optimize_pose_graph", never)
    monkeypatch.setattr(app.cmd_optimize, "check_writable", read_only)
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(out)]) == 2
    assert f"cannot write in {tmp_path}" in one_line_error(capsys.readouterr().err)


# ------------------------------------------------------------------------------- signals
def test_sigterm_after_importing_ceres_prints_no_crash_report() -> None:
    script = (
        "import os, signal, time\n"
        "import cogmap_core.optimizer\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(10)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == -signal.SIGTERM
    assert done.stderr == ""  # glog's handler printed "*** SIGTERM received ... stack trace"


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state != "Z"


def test_rendering_workers_exit_when_their_parent_is_killed(tmp_path: Path) -> None:
    script = (
        "import multiprocessing, sys, time\n"
        "from cogmap_core.datasets.generator import MazeConfig, plan_dataset, render_frames\n"
        "plan = plan_dataset(MazeConfig(layout='figure_eight', laps=1, fps=3.0))\n"
        "used, frames = render_frames(plan, workers=2, min_frames_per_worker=1)\n"
        "next(frames)\n"
        "print(' '.join(str(p.pid) for p in multiprocessing.active_children()), flush=True)\n"
        "time.sleep(60)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert len(workers) >= 2 and all(_alive(p) for p in workers)
        proc.kill()  # SIGKILL: the pool cannot be shut down
        proc.wait(timeout=30)
        deadline = time.monotonic() + 20
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers)
    finally:
        proc.kill()


@pytest.fixture
def ctrl_c_reaches_us() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt here, even in a suite started as a shell's background job
    (which starts with SIGINT ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("ctrl_c_reaches_us")
def test_ctrl_c_while_moving_the_report_into_place_is_held_back(
    bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    out = tmp_path / "out"
    old = old_report(bag, out)
    real_replace = os.replace
    moved: list[str] = []

    def replace(src: object, dst: object) -> None:
        if Path(str(dst)).parent == out:  # the commit moving staged files into out
            moved.append(Path(str(dst)).name)
            if len(moved) == 3:
                os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C half way through the move
        real_replace(src, dst)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "replace", replace)
    capsys.readouterr()
    assert main(["run", str(bag), "--out", str(out), "--force", "--delta", "6"]) == 130
    assert capsys.readouterr().err.rstrip().endswith("cogmap run: interrupted")
    after = snapshot(out)
    assert set(after) == REPORT and len(moved) == len(REPORT)  # every file, marker last
    assert moved[-1] == MARKER
    assert moved == [*REPORT_ORDER, MARKER]
    assert json.loads(after["summary.json"])["params"]["delta"] == 6.0  # type: ignore[arg-type]
    assert after["summary.json"] != old["summary.json"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
