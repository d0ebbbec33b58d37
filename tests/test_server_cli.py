"""``cogmap serve`` as a user runs it: URL printed, page served, Ctrl-C stops and frees the port."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from app.cli import main
from app.cmd_serve import display_url
from tests import test_server_support as support

short_bag = support.short_bag  # session fixture

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def port_is_free(port: int) -> bool:
    """Whether a server could listen on ``port`` now (as servers do, with SO_REUSEADDR)."""
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(("127.0.0.1", port))
            sock.listen()
        except OSError:
            return False
        return True


def start_serve(*args: str) -> tuple[subprocess.Popen[str], str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()  # blocks until the URL line (or EOF if it died)
    match = re.match(r"cogmap serve: (http://\S+)", line)
    if match is None:
        proc.kill()
        _, err = proc.communicate()
        pytest.fail(f"no URL line: {line!r}; stderr: {err}")
    return proc, match.group(1)


def page(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as response:
        assert response.status == 200
        return response.read()


def stop(proc: subprocess.Popen[str]) -> tuple[int, str]:
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("cogmap serve did not stop within 20 s of Ctrl-C")
    return proc.returncode, err


def test_serve_prints_its_url_serves_the_page_and_stops_cleanly_on_ctrl_c(short_bag: Path) -> None:
    port = free_port()
    proc, url = start_serve(str(short_bag), "--port", str(port), "--speed", "max")
    assert url == f"http://127.0.0.1:{port}"
    assert b"<html" in page(url).lower()
    time.sleep(1.0)  # let it replay for a moment
    code, err = stop(proc)
    assert code == 0, err
    assert "cogmap serve: stopped" in err
    assert "Traceback" not in err
    assert port_is_free(port)


def test_a_busy_port_moves_to_the_next_free_one(short_bag: Path) -> None:
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        busy = blocker.getsockname()[1]
        proc, url = start_serve(str(short_bag), "--port", str(busy), "--paused")
        try:
            used = int(url.rsplit(":", 1)[1])
            assert used != busy
            assert b"<html" in page(url).lower()
        finally:
            code, err = stop(proc)
        assert code == 0
        assert f"port {busy} is busy; using {used}" in err
        assert port_is_free(used)


def test_a_missing_bag_is_reported_on_stderr_and_the_page_is_served(tmp_path: Path) -> None:
    missing = tmp_path / "missing.bag"
    proc, url = start_serve(str(missing), "--port", str(free_port()))
    assert b"<html" in page(url).lower()
    code, err = stop(proc)
    assert code == 0
    assert f"cogmap serve: error: bag {missing} does not exist; check the path" in err


def test_bad_arguments_fail_fast_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", "--delta", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cogmap serve: error: delta=0.5 is out of range")
    assert "\n" not in err
    assert main(["serve", "--port", "70000"]) == 2
    assert "port 70000 is out of range" in capsys.readouterr().err
    assert main(["serve", "--frontend", "vt_match_threshold"]) == 2
    assert "write KEY=VALUE" in capsys.readouterr().err
    # a missing log with its ground truth named: refused now, not silently served without it
    assert main(["serve", "missing_odometry.csv", "--ground-truth", "gt.csv"]) == 2
    err = capsys.readouterr().err.strip()
    expected = (
        "missing_odometry.csv: no such file; give a bag, a video, a folder of images, a TUC log "
        "or a CSV log"
    )
    assert err == f"cogmap serve: error: {expected}"
    # --resume continues on a bag: a missing one is refused, worded without "or omit BAG"
    assert main(["serve", "missing.bag", "--resume", "s.npz"]) == 2
    err = capsys.readouterr().err.strip()
    expected = "missing.bag: no such bag; --resume continues on an existing .bag file"
    assert err == f"cogmap serve: error: {expected}"
    assert main(["serve", "--resume", "s.npz"]) == 2
    err = capsys.readouterr().err.strip()
    expected = "--resume needs a bag to continue on: cogmap serve BAG --resume FILE"
    assert err == f"cogmap serve: error: {expected}"


def test_display_url() -> None:
    # every interface: this machine's name (colleagues open it), with the token (issue 24)
    assert (
        display_url("0.0.0.0", 8080, "t0k3n") == f"http://{socket.gethostname()}:8080/?token=t0k3n"
    )
    assert display_url("127.0.0.1", 81) == "http://127.0.0.1:81"
    assert display_url("::1", 8080) == "http://[::1]:8080"
