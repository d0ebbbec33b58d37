"""The probes of issue 24, rerun: each hostile case's answer, time and peak memory.

Every case runs in a child process of its own (peak memory is that process's ``ru_maxrss``; its
virtual memory is capped at 4 GiB so that a regression fails instead of eating the machine) and
must give a one-line refusal or a correct result within 10 s and 2 GB. The web-app cases start a
guarded server on loopback in the child and probe it as a visitor would (websocket, HTTP); the
others run ``cogmap run`` on files made in a temporary folder (a 12-frame bag, a session of it,
a 6 GiB array in a 6 MB ``.npz``, ...).

    python benchmarks/hostile_inputs.py [--only SUBSTRING] [--markdown]

Prints one line per case (``--markdown``: a table) and exits 1 when a case misses its target.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_322_449_200 * 10**9
LIMIT_S = 10.0
LIMIT_MB = 2000.0


# ------------------------------------------------------------------------------------ inputs
def jpeg(k: int) -> bytes:
    yy, xx = np.mgrid[0:240, 0:416]
    ok, buf = cv2.imencode(".jpg", ((xx * (k + 1) + yy * 3 + k * 17) % 256).astype(np.uint8))
    assert ok
    return buf.tobytes()


def forged_jpeg(width: int, height: int) -> bytes:
    data = bytearray(jpeg(0))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


def forged_png(width: int, height: int) -> bytes:
    ok, buf = cv2.imencode(".png", np.zeros((240, 416), np.uint8))
    assert ok
    data = bytearray(buf.tobytes())
    data[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")
    data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")
    return bytes(data)


def bag(path: Path, frame: Callable[[int], bytes], n: int = 12) -> Path:
    from cogmap_core.datasets.bag_writer import IratBagWriter

    with IratBagWriter(path) as writer:
        for k in range(2 * n + 2):
            t = T0 + k * 100_000_000
            writer.write_odometry(t, 0.1, 0.01)
            writer.write_ground_truth(t, 0.01 * k, 0.0, 0.001 * k)
            if k % 2 == 1 and k // 2 < n:
                writer.write_image(t, frame(k // 2))
    return path


def npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array)
    return buffer.getvalue()


def session_copy(
    source: Path, target: Path, header: str | None, drop: tuple[str, ...] = ()
) -> zipfile.ZipFile:
    archive = zipfile.ZipFile(target, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1)
    with zipfile.ZipFile(source) as src:
        for item in src.infolist():
            name = item.filename.removesuffix(".npy")
            if name in drop:
                continue
            data = npy(np.array(header)) if name == "header" and header is not None else None
            archive.writestr(item.filename, data if data is not None else src.read(item))
    return archive


def zeros_member(archive: zipfile.ZipFile, name: str, count: int) -> None:
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "|u1", "fortran_order": False, "shape": (count,)}
    )
    chunk = bytes(64 << 20)
    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
        member.write(header.getvalue())
        for start in range(0, count, len(chunk)):
            member.write(chunk[: min(len(chunk), count - start)])


def session_header(path: Path) -> dict:
    with zipfile.ZipFile(path) as src, src.open("header.npy") as member:
        return json.loads(str(np.lib.format.read_array(member)))


def prepare(work: Path) -> dict[str, Path]:
    """The input files of the command-line cases (not timed)."""
    from app.cli import main

    files: dict[str, Path] = {}
    files["bag"] = bag(work / "tiny.bag", jpeg)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        main(["run", str(files["bag"]), "--out", str(work / "r0"), "--save-session",
              str(work / "tiny.session.npz")])  # fmt: skip
    session = files["session"] = work / "tiny.session.npz"
    files["bomb"] = work / "bomb.session.npz"
    with session_copy(session, files["bomb"], None, drop=("frontend.templates",)) as archive:
        zeros_member(archive, "frontend.templates", 6 << 30)  # 6 GiB of zeros in ~6 MB
    header = session_header(session)
    header["frontend"].update(pc_dim_xy=1000, pc_dim_th=3600)
    files["maximal"] = work / "maximal.session.npz"
    session_copy(session, files["maximal"], json.dumps(header)).close()
    files["deep_session"] = work / "deep.session.npz"
    session_copy(session, files["deep_session"], "[" * 200_000 + "]" * 200_000).close()
    huge_jpeg = forged_jpeg(65000, 65000)
    huge_png = forged_png(30000, 30000)
    files["jpeg_bag"] = bag(work / "jpeg65000.bag", lambda k: huge_jpeg if k % 3 else jpeg(k))
    files["png_bag"] = bag(work / "png30000.bag", lambda k: huge_png if k % 3 else jpeg(k))
    (work / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (work / "int.json").write_text('{"delta": 1' + "0" * 399 + "}")
    (work / "true.json").write_text('{"alpha": true}')
    best = {"format": "cogmap-sweep-best", "smallest_complete": [1, 2], "paper": "x"}
    (work / "best.json").write_text(json.dumps(best))
    tuc = work / "three_Input.txt"
    tuc.write_text("".join(f"odom2 {0.1 * k:.1f} 0.1 0.0 0.0 0 0 0\n" for k in range(3)))
    (work / "three_GT.txt").write_text(
        "".join(f"point2 {0.1 * k:.1f} {0.01 * k:.2f} 0.0 0 0 0 0\n" for k in range(3))
    )
    files["tuc"] = tuc
    return files


# ------------------------------------------------------------------------ web-app scenarios
def _app(work: Path, host: str = "127.0.0.1", **policy: object) -> tuple[Any, Any]:
    from app.server.access import AccessPolicy, guarded_server
    from app.server.app import CogmapApp

    data = work / "data"
    data.mkdir(exist_ok=True)
    server = guarded_server(host, 0, AccessPolicy(**policy), quiet=True)  # type: ignore[arg-type]
    tiny = bag(data / "tiny.bag", jpeg)
    app = CogmapApp(server, tiny, speed=float("inf"), export_dir=work / "exports",
                    data_dirs=[data], rebuild_workers=0)  # fmt: skip
    app.start()
    app.wait_idle(60)
    return server, app


def _client(port: int, **kwargs: object) -> Any:
    import viser
    from websockets.sync.client import connect

    from tests.test_server_support import camera_message

    ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                 open_timeout=10, **kwargs)  # type: ignore[list-item,arg-type]  # fmt: skip
    ws.send(camera_message())
    return ws


def _save(app: Any, ws: Any, name: str) -> str:
    from tests.test_server_support import send, until

    send(ws, app.replay_path, value=name)
    until(lambda: app.replay_path.value == name, 10)
    before = app.export.saving
    send(ws, app.replay_button, value=True)
    until(lambda: app.export.saving is not before, 10)
    app.export.saving.join(60)
    return app.export_md.content


def _text(content: str) -> str:
    import html
    import re

    return html.unescape(re.sub(r"<[^>]+>", "", content))


def web_save_paths(work: Path) -> str:
    import app.server.panels.export as export_panel
    from app.server.export import save_html_replay
    from tests.test_server_support import until

    export_panel.save_html_replay = functools.partial(save_html_replay, keyframes=5, seconds=0.5)
    server, app = _app(work)
    ws = _client(server.get_port())
    until(lambda: len(server.get_clients()) == 1)
    for name in ("/etc/cron.d/cogmap.html", "~/pwned.html", "x/a/b/c/x.html"):
        _save(app, ws, name)
    ws.close()
    app.stop()
    server.stop()
    names = sorted(p.name for p in (work / "exports").iterdir())
    assert not Path("/etc/cron.d/cogmap.html").exists()
    return f"saved in the export folder only, as {', '.join(names)}"


def web_huge_html(work: Path) -> str:
    from tests.test_server_support import until

    (work / "exports").mkdir()
    with (work / "exports" / "big.html").open("wb") as handle:
        handle.truncate(10 << 30)  # 10 GiB, sparse
    server, app = _app(work)
    ws = _client(server.get_port())
    until(lambda: len(server.get_clients()) == 1)
    answer = _text(_save(app, ws, "big.html"))
    ws.close()
    app.stop()
    server.stop()
    return answer


def web_other_origin(work: Path) -> str:
    from websockets.exceptions import InvalidStatus

    server, app = _app(work)
    port = server.get_port()
    try:
        _client(port, origin=f"http://127.0.0.1:{port + 1}").close()
        answer = "OPENED"
    except InvalidStatus as exc:
        answer = f"websocket refused: HTTP {exc.response.status_code}"
    app.stop()
    server.stop()
    return answer


def web_every_interface(work: Path) -> str:
    import urllib.error
    import urllib.request

    from app.server.access import new_token

    server, app = _app(work, host="0.0.0.0", token=new_token(), loopback_only=False)
    port = server.get_port()
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10)
        answer = "PAGE SERVED WITHOUT TOKEN"
    except urllib.error.HTTPError as exc:
        answer = f"page without the token: HTTP {exc.code}"
    app.stop()
    server.stop()
    return answer


def web_fifo(work: Path) -> str:
    from tests.test_server_support import send, until

    data = work / "data"
    data.mkdir()
    os.mkfifo(data / "pipe.bag")
    server, app = _app(work)
    answers = []
    for name in (str(data / "pipe.bag"), "/dev/stdin", "pipe.bag"):
        app.open_bag(name)
        answers.append(_text(app.open_md.content))
    ws = _client(server.get_port())
    until(lambda: len(server.get_clients()) == 1)
    send(ws, app.play_button, value=True)
    until(lambda: app.replay.state.value in ("playing", "ended"), 10)
    ws.close()
    app.stop()
    server.stop()
    return answers[1] + " (play still works)"


def web_ssh_key(work: Path) -> str:
    server, app = _app(work)
    app.open_bag("~/.ssh/id_rsa")
    answer = _text(app.open_md.content)
    app.stop()
    server.stop()
    return answer


SCENARIOS: dict[str, Callable[[Path], str]] = {
    "web_save_paths": web_save_paths,
    "web_huge_html": web_huge_html,
    "web_other_origin": web_other_origin,
    "web_every_interface": web_every_interface,
    "web_fifo": web_fifo,
    "web_ssh_key": web_ssh_key,
}


# ------------------------------------------------------------------------------------- cases
def cases(files: dict[str, Path], work: Path) -> list[tuple[str, str, list[str]]]:
    """(issue item, case, child arguments): ``cli ARGS`` runs ``cogmap ARGS``."""
    outs = (str(work / f"out{k}") for k in range(100))  # a report folder per case
    run = ["cli", "run"]
    return [
        ("1", "save replay as /etc/cron.d/…, ~/…, x/a/b/c/…", ["web", "web_save_paths"]),
        ("1", "a 10 GiB .html in the way", ["web", "web_huge_html"]),
        ("2", "websocket from another origin (loopback)", ["web", "web_other_origin"]),
        ("2", "page on 0.0.0.0 without the token", ["web", "web_every_interface"]),
        ("3", "open a FIFO, /dev/stdin", ["web", "web_fifo"]),
        ("4", "open ~/.ssh/id_rsa", ["web", "web_ssh_key"]),
        ("5", "session with a 6 GiB array (6 MB file)",
         [*run, str(files["bag"]), "--out", next(outs), "--resume", str(files["bomb"])]),
        ("5", "session header: pose cells 1000 x 1000 x 3600",
         [*run, str(files["bag"]), "--out", next(outs), "--resume", str(files["maximal"])]),
        ("5", "bag with JPEG frames of 65000 x 65000",
         [*run, str(files["jpeg_bag"]), "--out", next(outs)]),
        ("5", "bag with PNG frames of 30000 x 30000",
         [*run, str(files["png_bag"]), "--out", next(outs)]),
        ("6", "run BAG --delta 1000",
         [*run, str(files["bag"]), "--out", next(outs), "--delta", "1000"]),
        ("6", "3-line TUC log with ground truth", [*run, str(files["tuc"]), "--out", next(outs)]),
        ("7", "--params nested 100k deep",
         [*run, str(files["bag"]), "--out", next(outs), "--params", str(work / "deep.json")]),
        ("7", "--params with a 400-digit integer",
         [*run, str(files["bag"]), "--out", next(outs), "--params", str(work / "int.json")]),
        ("7", '--params {"alpha": true}',
         [*run, str(files["bag"]), "--out", next(outs), "--params", str(work / "true.json")]),
        ("7", "best.json entry that is a list",
         [*run, str(files["bag"]), "--out", next(outs), "--params", str(work / "best.json")]),
        ("7", "best.json entry that is a string",
         [*run, str(files["bag"]), "--out", next(outs), "--params", f"{work / 'best.json'}#paper"]),
        ("7", "session header nested 200k deep",
         [*run, str(files["bag"]), "--out", next(outs), "--resume", str(files["deep_session"])]),
    ]  # fmt: skip


CHILD = r"""
import resource, sys, time
limit = 4 * 1024**3
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
sys.path.insert(0, sys.argv[1])
started = time.perf_counter()
kind, args = sys.argv[2], sys.argv[3:]
if kind == "cli":
    import contextlib, io
    from app.cli import main
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = main(args)
    lines = [l for l in err.getvalue().replace("\r", "\n").splitlines() if "error:" in l
             or "Traceback" in l]
    warned = [l for l in out.getvalue().splitlines() if l.startswith("warning:")]
    answer = lines[-1] if lines else "; ".join([f"exit {code}, report written", *warned])
else:
    import pathlib, benchmarks.hostile_inputs as h
    answer = h.SCENARIOS[args[0]](pathlib.Path(args[1]))
seconds = time.perf_counter() - started
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(f"{seconds:.3f} {peak:.0f} {answer}")
"""


def measure(argv: list[str], work: Path) -> tuple[float, float, str]:
    scratch = Path(tempfile.mkdtemp(dir=work))
    if argv[0] == "web":
        argv = [*argv, str(scratch)]
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(ROOT), *argv],
        capture_output=True, text=True, timeout=120, cwd=scratch,
        env=dict(os.environ, HOME=str(scratch), COGMAP_CACHE=str(scratch / "cache")),
    )  # fmt: skip
    last = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    try:
        seconds, peak, answer = last.split(" ", 2)
        return float(seconds), float(peak), answer.replace(str(work), "…")
    except ValueError:
        tail = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return float("nan"), float("nan"), f"FAILED: {tail}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="run the cases whose name holds this text")
    parser.add_argument("--markdown", action="store_true", help="print a markdown table")
    args = parser.parse_args()
    missed = 0
    with tempfile.TemporaryDirectory(prefix="cogmap-hostile-") as tmp:
        work = Path(tmp)
        started = time.perf_counter()
        files = prepare(work)
        print(f"(inputs made in {time.perf_counter() - started:.1f} s)", file=sys.stderr)
        for item, name, argv in cases(files, work):
            if args.only not in name:
                continue
            seconds, peak, answer = measure(argv, work)
            ok = seconds <= LIMIT_S and peak <= LIMIT_MB and "Traceback" not in answer
            ok = ok and not answer.startswith(("FAILED", "OPENED", "PAGE SERVED"))
            missed += not ok
            short = answer if len(answer) <= 150 else answer[:147] + "…"
            if args.markdown:
                print(f"| {item}. {name} | {short} | {seconds:.2f} s | {peak:.0f} MB |")
            else:
                flag = "OK" if ok else "MISSED"
                print(f"[{item}] {name:48} {seconds:7.2f} s {peak:6.0f} MB  {flag}  {short}")
    print(f"{'all cases within' if not missed else f'{missed} case(s) beyond'} "
          f"{LIMIT_S:.0f} s and {LIMIT_MB:.0f} MB, each with one line or a result")  # fmt: skip
    return 1 if missed else 0


if __name__ == "__main__":
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    sys.exit(main())
