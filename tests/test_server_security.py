"""The web app shared on a network, probed as a visitor with hostile intent would (issue 24).

Items 1-4 of the issue, each against a real server on loopback: a visitor writes only into the
export folder, under a safe name; pages of another origin and requests without the token are
refused; no visitor can make the server open a FIFO or a device, nor learn what exists outside
the data folders or where the server is installed.
"""

from __future__ import annotations

import functools
import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tracemalloc
import types
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import viser
import websockets.asyncio.server
import websockets.datastructures
import websockets.exceptions
import zstandard
from websockets.sync.client import ClientConnection, connect

import app.server.files as files_module
import app.server.panels.export as export_panel
from app.server.access import AccessGateError, AccessPolicy, guarded_server
from app.server.app import CogmapApp
from app.server.export import save_html_replay
from tests import test_server_support as support
from tests.test_server_support import camera_message, running_app, send, until, wait

short_bag = support.short_bag  # session fixture
ROOT = Path(__file__).resolve().parents[1]
VISER = f"viser-v{viser.__version__}"


def open_ws(port: int, path: str = "", **kwargs: object) -> ClientConnection:
    """A browser-like websocket to the server (its camera sent, as a tab does first)."""
    ws = connect(f"ws://127.0.0.1:{port}{path}", subprotocols=[VISER], open_timeout=10, **kwargs)  # type: ignore[list-item,arg-type]
    ws.send(camera_message())
    return ws


def refused(port: int, path: str = "", **kwargs: object) -> int:
    """The HTTP status with which the websocket handshake was refused (fails if it opened)."""
    try:
        ws = connect(
            f"ws://127.0.0.1:{port}{path}", subprotocols=[VISER], open_timeout=10, **kwargs
        )  # type: ignore[list-item,arg-type]
    except websockets.exceptions.InvalidStatus as exc:
        return exc.response.status_code
    ws.close()
    raise AssertionError("the websocket opened")


#: What a browser's websocket handshake sends (with ``Host`` given: one can be spoofed).
UPGRADE = {
    "Upgrade": "websocket",
    "Connection": "Upgrade",
    "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
    "Sec-WebSocket-Version": "13",
    "Sec-WebSocket-Protocol": VISER,
}


def get(
    port: int, path: str = "/", headers: dict[str, str] | None = None
) -> tuple[int, dict, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path, headers=headers or {})
        response = conn.getresponse()
        return response.status, dict(response.getheaders()), response.read()
    finally:
        conn.close()


def frames(ws: ClientConnection, seconds: float) -> Iterator[dict]:
    """The messages the server sends ``ws`` for ``seconds`` (viser's wire format decoded)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = ws.recv(timeout=0.05)
        except TimeoutError:
            continue
        assert isinstance(data, bytes)
        size = int.from_bytes(data[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompressobj().decompress(data[16 : 16 + size])
        yield from (m for m in msgspec.msgpack.decode(inner)["messages"] if isinstance(m, dict))


def controls(ws: ClientConnection, seconds: float = 2.0) -> dict[str, str]:
    """The page's controls as a browser learns them: ``"<kind> <label>"`` -> uuid."""
    found: dict[str, str] = {}
    for message in frames(ws, seconds):
        kind = str(message.get("type", ""))
        label = (message.get("props") or {}).get("label")
        if kind.startswith("Gui") and label:
            found[f"{kind.removeprefix('Gui').removesuffix('Message').lower()} {label}"] = str(
                message["uuid"]
            )
    return found


def update(ws: ClientConnection, uuid: str, value: object) -> None:
    ws.send(
        msgspec.msgpack.encode(
            {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": value}}
        )
    )


@pytest.fixture
def quick_replays(monkeypatch: pytest.MonkeyPatch) -> None:
    """HTML replays of 5 key frames (the page's 240 take seconds each)."""
    monkeypatch.setattr(
        export_panel,
        "save_html_replay",
        functools.partial(save_html_replay, keyframes=5, seconds=0.5),
    )


def saved(app: CogmapApp, ws: ClientConnection, name: str) -> str:
    """Type ``name`` as the replay's name and click "save HTML replay"; the message shown."""
    send(ws, app.replay_path, value=name)
    until(lambda: app.replay_path.value == name, 10, "the name typed")
    before = app.export.saving
    send(ws, app.replay_button, value=True)
    until(lambda: app.export.saving is not before, 10, "the save to start")
    assert app.export.saving is not None
    app.export.saving.join(60)
    return app.export_md.content


# ----------------------------------------------------- item 1: files only in the export folder
def test_a_visitor_writes_only_into_the_export_folder_under_a_safe_name(
    short_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, quick_replays: None
) -> None:
    home, cwd, exports = tmp_path / "home", tmp_path / "cwd", tmp_path / "exports"
    home.mkdir()
    cwd.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(cwd)
    outside = tmp_path / "etc" / "cron.d" / "cogmap.html"
    # "/" becomes "_", the name is cut to 80 characters (75 before its suffix)
    flat = (
        outside.relative_to("/").as_posix().replace("/", "_").removesuffix(".html")[:75] + ".html"
    )
    with running_app(short_bag, export_dir=exports) as app:
        wait(app)
        ws = open_ws(app.server.get_port())
        until(lambda: len(app.server.get_clients()) == 1)
        for typed, name in (
            (str(outside), flat),
            ("~/pwned.html", "pwned.html"),
            ("x/a/b/c/x.html", "x_a_b_c_x.html"),
            ("../../up.htm", "up.htm.html"),
            ("..", "cogmap-replay.html"),
        ):
            message = saved(app, ws, typed)
            assert f"saved the HTML replay as {name} in the export folder and sent it" in message
        ws.close()
    names = sorted(p.name for p in exports.iterdir())
    assert names == sorted(
        [
            flat,
            "pwned.html",
            "x_a_b_c_x.html",
            "up.htm.html",
            "cogmap-replay.html",
        ]
    )
    assert not (tmp_path / "etc").exists() and not any(home.iterdir()) and not any(cwd.iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cwd", "exports", "home"]


def test_a_file_in_the_way_is_never_read_whole_nor_followed(
    short_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, quick_replays: None
) -> None:
    exports = tmp_path / "exports"
    exports.mkdir()
    big = exports / "big.html"
    with big.open("wb") as handle:
        handle.truncate(1 << 30)  # 1 GiB (sparse): its first 64 kB are read, nothing more
    secret = tmp_path / "secret.txt"
    secret.write_text("not to be replaced")
    (exports / "link.html").symlink_to(secret)
    os.mkfifo(exports / "pipe.html")
    with running_app(short_bag, export_dir=exports) as app:
        wait(app)
        ws = open_ws(app.server.get_port())
        until(lambda: len(app.server.get_clients()) == 1)
        tracemalloc.start()
        try:
            for name in ("big.html", "link.html", "pipe.html"):
                started = time.monotonic()
                message = saved(app, ws, name)
                assert f"replay not saved: {name} exists in the export folder and is not a " in (
                    message
                )
                assert time.monotonic() - started < 5
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 20_000_000  # (reading big.html whole: 1 GB and more)
        # a replay of ours is replaced; beyond MAX_EXPORTS replays, new names are refused
        assert "saved the HTML replay as ours.html" in saved(app, ws, "ours.html")
        assert "saved the HTML replay as ours.html" in saved(app, ws, "ours.html")
        monkeypatch.setattr(files_module, "MAX_EXPORTS", 4)
        assert (
            "replay not saved: the export folder holds 4 replays already; remove some or reuse "
            "a name" in saved(app, ws, "more.html")
        )
        ws.close()
    assert big.stat().st_size == 1 << 30 and secret.read_text() == "not to be replaced"
    assert (exports / "link.html").is_symlink()


# ------------------------------------------------------------------ item 2: access control
def test_a_page_of_another_origin_cannot_open_the_websocket(short_bag: Path) -> None:
    """Loopback, no token: the same origin only, and only names of this machine (rebinding)."""
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        port = app.server.get_port()
        for origin in (f"http://127.0.0.1:{port + 1}", "http://evil.example", "null"):
            assert refused(port, origin=origin) == 403  # type: ignore[arg-type]
        host = {"Host": f"evil.example:{port}"}  # a name that resolves here: DNS rebinding
        assert get(port, headers={**host, **UPGRADE})[0] == 403
        assert get(port, headers=host)[0] == 403
        assert get(port, headers={**UPGRADE, "Host": f"localhost:{port}"})[0] == 101
        assert app.server.get_clients() == {}
        assert not app.replay.playing
        # the page itself: its origin connects, and drives the controls
        status, headers, body = get(port)
        assert status == 200 and b"<html" in body.lower()
        assert headers["X-Frame-Options"] == "DENY"
        assert headers["Referrer-Policy"] == "no-referrer"
        assert "Set-Cookie" not in headers
        ws = open_ws(port, origin=f"http://127.0.0.1:{port}")  # type: ignore[arg-type]
        until(lambda: len(app.server.get_clients()) == 1)
        send(ws, app.play_button, value=True)
        until(lambda: app.replay.playing, 10, "play")
        ws.close()


def serve(*args: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("cogmap serve: http://"):
        proc.kill()
        pytest.fail(f"no URL line: {line!r}; stderr: {proc.communicate()[1]}")
    return proc, line.split()[2]


def stop(proc: subprocess.Popen[str], sig: int = signal.SIGINT) -> tuple[int, str]:
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"cogmap serve did not stop within 20 s of signal {sig}")
    return proc.returncode, err


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_every_interface_needs_the_token_and_says_so(short_bag: Path, tmp_path: Path) -> None:
    port = free_port()
    proc, url = serve(
        str(short_bag), "--host", "0.0.0.0", "--port", str(port), "--paused",
        "--export-dir", str(tmp_path / "exports"),
    )  # fmt: skip
    try:
        prefix = f"http://{socket.gethostname()}:{port}/?token="
        assert url.startswith(prefix)
        token = url.removeprefix(prefix)
        assert len(token) == 32
        # without the token: neither the page nor the websocket
        status, _, body = get(port)
        assert status == 403 and b"needs its token" in body and token.encode() not in body
        assert get(port, "/?token=" + "x" * 32)[0] == 403
        assert refused(port) == 403
        assert refused(port, f"/?token={token[:-1]}") == 403
        # with it: the page, which sets it as a cookie the websocket then carries
        status, headers, body = get(port, f"/?token={token}")
        assert status == 200 and b"<html" in body.lower()
        cookie = f"cogmap-token-{port}={token}"
        assert headers["Set-Cookie"] == f"{cookie}; Path=/; HttpOnly; SameSite=Strict"
        assert get(port, "/", {"Cookie": f"other=1; {cookie}"})[0] == 200
        open_ws(port, f"/?token={token}").close()
        open_ws(port, additional_headers={"Cookie": cookie}).close()  # type: ignore[arg-type]
        # the token does not let another origin in
        assert refused(port, f"/?token={token}", origin="http://evil.example") == 403  # type: ignore[arg-type]
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert (
        f"cogmap serve: warning: listening on every network interface, port {port}: anyone who "
        "has the URL below and can reach this machine can watch and steer the replay, open the "
        "bags of the data folders and save replays in the export folder; see docs/security.md"
    ) in err
    assert "Traceback" not in err


def test_no_token_is_a_choice_and_loopback_stays_token_free(short_bag: Path) -> None:
    port = free_port()
    proc, url = serve(str(short_bag), "--host", "0.0.0.0", "--port", str(port), "--no-token")
    try:
        assert url == f"http://{socket.gethostname()}:{port}"
        assert get(port)[0] == 200
    finally:
        code, err = stop(proc)
    assert code == 0 and "anyone (--no-token: no token is asked)" in err
    port = free_port()
    proc, url = serve(str(short_bag), "--port", str(port), "--require-token")
    try:
        assert url.startswith(f"http://127.0.0.1:{port}/?token=")
        assert (
            get(port)[0] == 403
            and get(port, url.removeprefix(f"http://127.0.0.1:{port}"))[0] == 200
        )
    finally:
        code, err = stop(proc)
    assert code == 0 and "warning" not in err


def test_a_viser_that_serves_another_way_is_never_left_unguarded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The gate hooks viser's use of websockets' ``serve``; without it, no server at all."""
    import viser.infra._infra as infra

    direct = types.SimpleNamespace(  # websockets as viser would see it, serve not replaceable
        asyncio=types.SimpleNamespace(server=types.SimpleNamespace(
            serve=websockets.asyncio.server.serve,
            ServerConnection=websockets.asyncio.server.ServerConnection,
        )),
        exceptions=websockets.exceptions,
        datastructures=websockets.datastructures,
    )  # fmt: skip
    port = free_port()
    monkeypatch.setattr(infra, "websockets", direct)
    with pytest.raises(AccessGateError, match="does not serve its page through the hook"):
        guarded_server("127.0.0.1", port, AccessPolicy(), quiet=True)
    monkeypatch.undo()
    with socket.socket() as sock:  # the unguarded server was stopped: its port is free
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", port))
    server = guarded_server("127.0.0.1", port, AccessPolicy(), quiet=True)  # the real one is
    try:
        assert server.access_gate.installed  # type: ignore[attr-defined]
        assert refused(server.get_port(), origin="http://evil.example") == 403  # type: ignore[arg-type]
    finally:
        server.stop()


# ------------------------------------------------------- item 3: nothing blocks the server
def opened_within(app: CogmapApp, name: str, seconds: float = 5.0) -> tuple[bool, str]:
    """``app.open_bag(name)`` on a thread; it must return within ``seconds``."""
    result: list[bool] = []
    thread = threading.Thread(target=lambda: result.append(app.open_bag(name)), daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"opening {name!r} blocked"
    return result[0], app.open_md.content


def not_listed(name: str) -> str:
    return (
        f"not opened: {name!r} is not one of the bags in the data folders (refresh the list to "
        "see new ones)"
    ).replace("'", "&#x27;")


def test_a_fifo_or_a_device_is_never_opened(short_bag: Path, tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    os.mkfifo(data / "pipe.bag")
    (data / "stdin.bag").symlink_to("/dev/stdin")
    (data / "zero.bag").symlink_to("/dev/zero")
    (data / "elsewhere.bag").symlink_to(short_bag)  # a bag, but outside the data folder
    (data / "ok.bag").write_bytes(short_bag.read_bytes())
    with running_app(short_bag, data_dirs=[data], autoplay=False) as app:
        wait(app)
        assert tuple(app.bag_dropdown.options) == ("ok.bag",)
        for name in (str(data / "pipe.bag"), "pipe.bag", "/dev/stdin", "stdin.bag", "zero.bag",
                     "elsewhere.bag"):  # fmt: skip
            assert opened_within(app, name) == (False, not_listed(name).join(
                ('<div class="cogmap-note cogmap-error" id="cogmap-open">', "</div>")
            ))  # fmt: skip
        # listed as a bag, then replaced by a FIFO: checked again, never opened
        (data / "ok.bag").unlink()
        os.mkfifo(data / "ok.bag")
        ok, message = opened_within(app, "ok.bag")
        assert not ok and "not opened: ok.bag is not a regular file any more; not opened" in message
        app.refresh_bags()
        assert tuple(app.bag_dropdown.options) == ("(no bag in the data folders)",)
        # a visitor sending a path instead of a choice is refused before any callback
        ws = open_ws(app.server.get_port())
        until(lambda: len(app.server.get_clients()) == 1)
        refusals = app.gate.refused
        for value in ("/dev/stdin", str(data / "pipe.bag"), 7):
            send(ws, app.bag_dropdown, value=value)
        until(lambda: app.gate.refused == refusals + 3, 10, "the refusals")
        send(ws, app.open_button, value=True)
        until(lambda: "(no bag in the data folders)" in app.open_md.content, 10, "the refusal")
        # and the server still plays
        send(ws, app.play_button, value=True)
        until(lambda: app.replay.playing, 10, "play")
        ws.close()


def test_serve_stops_on_sigterm_after_a_visitor_tried_a_fifo(
    short_bag: Path, tmp_path: Path
) -> None:
    data = tmp_path / "data"
    data.mkdir()
    os.mkfifo(data / "pipe.bag")
    os.mkfifo(data / "other.bag")
    port = free_port()
    proc, _ = serve(
        str(short_bag), "--port", str(port), "--paused", "--data-dir", str(data),
        "--export-dir", str(tmp_path / "exports"),
    )  # fmt: skip
    try:
        ws = open_ws(port)
        found = controls(ws)
        for value in ("pipe.bag", "/dev/stdin", "other.bag"):
            update(ws, found["dropdown bag or log"], value)
            update(ws, found["button open"], True)
        update(ws, found["button play"], True)
        assert any(
            "playing" in str(m.get("updates", {}).get("content", ""))
            for m in frames(ws, 3.0)
            if m.get("type") == "GuiUpdateMessage"
        )
        ws.close()
        started = time.monotonic()
    finally:
        code, err = stop(proc, signal.SIGTERM)
    assert code == 0 and time.monotonic() - started < 10
    assert "cogmap serve: stopped" in err and "Traceback" not in err


# ------------------------------------------------------------- item 4: nothing leaks out
def test_a_visitor_cannot_tell_what_exists_outside_the_data_folders(
    short_bag: Path, tmp_path: Path
) -> None:
    data = tmp_path / "data"
    data.mkdir()
    (tmp_path / "folder.bag").mkdir()
    (tmp_path / "exists.bag").write_bytes(short_bag.read_bytes())
    with running_app(short_bag, data_dirs=[data], autoplay=False) as app:
        wait(app)
        answers = {}
        for name in ("~/.ssh/id_rsa", str(tmp_path / "missing.bag"), str(tmp_path / "folder.bag"),
                     str(tmp_path / "exists.bag"), "/etc/passwd", "../exists.bag"):  # fmt: skip
            ok, message = opened_within(app, name)
            assert not ok
            answers[name] = message.replace(repr(name).replace("'", "&#x27;"), "NAME")
        assert len(set(answers.values())) == 1, answers  # the same line, whatever exists
        # summary.json names the bag, not its server path (here outside the data folders)
        sent: list[tuple[str, bytes]] = []
        visitor = types.SimpleNamespace(send_file_download=lambda n, c, **_: sent.append((n, c)))
        app.export.download(visitor, "summary")  # type: ignore[arg-type]
        assert json.loads(sent[0][1])["dataset"] == short_bag.name == "figure_eight_1lap.bag"


def test_no_server_path_reaches_a_browser(short_bag: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 100)
    with running_app(broken, autoplay=False, export_dir=tmp_path / "exports") as app:
        wait(app)
        assert app.open_bag("broken.bag") is False
        ws = open_ws(app.server.get_port())
        seen = " ".join(str(m) for m in frames(ws, 2.0))
        ws.close()
        assert "broken.bag has a damaged bag header" in seen  # the page shows the errors...
        assert "cogmap-replay-compact.html" in seen
        for secret in (str(ROOT), str(tmp_path), str(Path.home())):
            assert secret not in seen  # ...naming no server path (install, data, home)


def test_the_token_and_what_loopback_is() -> None:
    from app.server.access import is_loopback, new_token, policy_for
    from cogmap_core.errors import CogmapError

    assert all(is_loopback(h) for h in ("localhost", "127.0.0.1", "127.5.6.7", "::1", "[::1]"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "::", "10.0.0.1", "example.org", ""))
    made = {new_token({}) for _ in range(3)}
    assert len(made) == 3 and all(len(t) == 32 for t in made)
    assert new_token({"COGMAP_TOKEN": "a-fixed_token.of~20"}) == "a-fixed_token.of~20"
    for bad in ("short", "sixteen chars!!!", "x" * 15):
        with pytest.raises(CogmapError, match="COGMAP_TOKEN must be at least 16 characters"):
            new_token({"COGMAP_TOKEN": bad})
    assert policy_for("127.0.0.1").token is None and policy_for("127.0.0.1").loopback_only
    assert policy_for("0.0.0.0").token is not None and not policy_for("0.0.0.0").loopback_only
    assert policy_for("0.0.0.0", no_token=True).token is None
    assert policy_for("localhost", require_token=True).token is not None
