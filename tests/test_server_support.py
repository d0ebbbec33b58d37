"""Shared fixtures of the web-app tests: a short generated bag, its reference session, a server.

The reference is a :class:`SlamSession` run over the same bag without the web app; the app's maps
must equal it (and its ``rebuild`` results) exactly.
"""

from __future__ import annotations

import contextlib
import math
import re
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgspec
import numpy as np
import pytest
import viser
from websockets.sync.client import ClientConnection, connect

from app.server.access import AccessPolicy, guarded_server
from app.server.app import CogmapApp
from cogmap_core.cognitive_map import CognitiveMap
from cogmap_core.datasets import MazeConfig, generate_maze_bag, open_bag
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.slam import SlamSession

# One lap of the figure-eight maze at 6 frames/s: about 400 frames, 67 s of data.
SHORT_BAG = MazeConfig(layout="figure_eight", laps=1, fps=6.0)


@pytest.fixture(scope="session")
def short_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("server-bag") / "figure_eight_1lap.bag"
    generate_maze_bag(path, SHORT_BAG, workers=1)
    return path


@pytest.fixture(scope="session")
def reference(short_bag: Path) -> SlamSession:
    session = SlamSession(frontend_config=frontend_config_for(short_bag))  # as cogmap run
    with open_bag(short_bag, image_scale=1) as reader:
        session.run(reader.frames())
    return session


#: A log with false loop closures, some of them at the same time as true ones (one place
#: recognition query, several candidates): 500 s in two look-alike corridors, 30 % false.
FALSE_LOG = ("--pattern", "parallel_corridors", "--duration", "500", "--seed", "1",
             "--false-fraction", "0.3")  # fmt: skip


@pytest.fixture(scope="session")
def false_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A TUC log (``corridors_Input.txt`` and its ground truth) made by ``cogmap make-log``."""
    from app.cli import main

    prefix = tmp_path_factory.mktemp("server-log") / "corridors"
    assert main(["make-log", str(prefix), *FALSE_LOG]) == 0
    return prefix.parent / "corridors_Input.txt"


def make_server(policy: AccessPolicy | None = None) -> viser.ViserServer:
    """A viser server on loopback (a port the OS chooses), guarded as ``cogmap serve``'s."""
    return guarded_server("127.0.0.1", 0, policy or AccessPolicy(), quiet=True)


@contextlib.contextmanager
def running_app(bag: Path, **kwargs: object) -> Iterator[CogmapApp]:
    """A started app on a private server (port chosen by the OS), stopped afterwards."""
    server = make_server()
    kwargs.setdefault("speed", math.inf)
    with tempfile.TemporaryDirectory(prefix="cogmap-exports-") as exports:
        kwargs.setdefault("export_dir", Path(exports))  # (never the user's cache)
        app = CogmapApp(server, bag, **kwargs)  # type: ignore[arg-type]
        try:
            app.start()
            yield app
        finally:
            app.stop()
            server.stop()


def wait(app: CogmapApp) -> None:
    """Wait until the replay has settled (played to where it stops, every rebuild done)."""
    assert app.wait_idle(60), "the replay did not settle"


def until(condition: Callable[[], object], timeout: float = 10.0, what: str = "") -> float:
    """Poll ``condition()`` until it is true; fail after ``timeout`` s; return the seconds taken."""
    started = time.monotonic()
    while not condition():
        if time.monotonic() - started > timeout:
            raise AssertionError(f"timed out after {timeout} s waiting for {what or condition}")
        time.sleep(0.005)
    return time.monotonic() - started


def assert_same_map(actual: CognitiveMap, expected: CognitiveMap) -> None:
    """Exactly the same graph: ids, edges, counts, optimisations; poses to 1e-9."""
    assert actual.mode == expected.mode
    assert actual.num_vertices == expected.num_vertices
    assert actual.num_edges == expected.num_edges
    assert actual.num_loop_edges == expected.num_loop_edges
    assert len(actual.clusters) == len(expected.clusters)
    assert len(actual.optimizations) == len(expected.optimizations)
    a, e = actual.snapshot(), expected.snapshot()
    np.testing.assert_array_equal(a.vertex_ids, e.vertex_ids)
    np.testing.assert_array_equal(a.edge_from, e.edge_from)
    np.testing.assert_array_equal(a.edge_to, e.edge_to)
    np.testing.assert_array_equal(a.edge_cluster, e.edge_cluster)
    np.testing.assert_allclose(a.poses, e.poses, rtol=0, atol=1e-9)


def counter(app: CogmapApp, key: str) -> str:
    """The text of counter ``cogmap-<key>`` on the page."""
    match = re.search(rf'id="cogmap-{re.escape(key)}"[^>]*>([^<]*)<', app.counters_html.content)
    assert match is not None, f"no counter {key} in {app.counters_html.content}"
    return match.group(1)


#: Flags for Debian's Chromium, headless on a machine without GPU or network (software WebGL).
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]


def camera_message(width: int = 1280, height: int = 800) -> bytes:
    """What a browser sends first (its camera); viser then treats the connection as a client."""
    return msgspec.msgpack.encode(
        {
            "type": "ViewerCameraMessage",
            "wxyz": (1.0, 0.0, 0.0, 0.0),
            "position": (0.0, 0.0, 5.0),
            "fov": 1.0,
            "near": 0.01,
            "far": 100.0,
            "image_height": height,
            "image_width": width,
            "look_at": (0.0, 0.0, 0.0),
            "up_direction": (0.0, 0.0, 1.0),
        }
    )


def client(port: int, *, hello: bool = True) -> ClientConnection:
    """A websocket connection to the server on ``port``, as a browser's tab opens it.

    With ``hello`` it sends its camera first (:func:`camera_message`), which makes viser treat
    it as a client; without, it stays a connection that never said hello.
    """
    ws = connect(
        f"ws://127.0.0.1:{port}",
        subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
        max_size=None,
        open_timeout=10,
    )
    if hello:
        ws.send(camera_message())
    return ws


def send(ws: ClientConnection, handle: object, **updates: object) -> None:
    """What a browser sends when its viewer changes ``handle``: ``send(ws, box, value="8")``."""
    uuid = handle._impl.uuid  # type: ignore[attr-defined]
    ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": updates}))
