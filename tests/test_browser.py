"""The page in a real browser: Debian's Chromium driven by playwright, the way a researcher uses it.

One session on a short generated bag: load the page (paused), play at max speed to the end, type
every tuning parameter -- a valid value, one out of range, garbage -- and see the counters
change to what ``SlamSession.rebuild`` gives (the time from Enter to the counter is printed),
switch maps, show two side by side, click a vertex, pin the map and compare after a change, open
a second tab with a view of its own, play and pause with the space bar, export summary.json and
an HTML replay. Screenshots of the final states are saved as artifacts (their paths are printed).

Skipped when Chromium is not installed, unless ``COGMAP_REQUIRE_BROWSER`` is set (CI sets it):
then a missing browser is a failure.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from app.server.params import SPECS, format_value
from app.server.scene import MAP_COLORS, PINNED_COLOR
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.slam import SlamSession
from tests import test_server_support as support
from tests.test_server_support import until, wait

short_bag = support.short_bag  # session fixtures
reference = support.reference

CHROMIUM = os.environ.get("COGMAP_CHROMIUM", "/usr/bin/chromium")
REQUIRED = bool(os.environ.get("COGMAP_REQUIRE_BROWSER"))
ARGS = support.CHROMIUM_ARGS
ARTIFACTS = Path(
    os.environ.get("COGMAP_ARTIFACTS", Path(tempfile.gettempdir()) / "cogmap-artifacts")
)
TIMEOUT_MS = 30_000

pytestmark = pytest.mark.browser

#: Per parameter: a valid value, one out of range (clamped to the bound), garbage (refused).
TYPED: tuple[tuple[str, str, str, str], ...] = (
    ("alpha", "40", "1e9", "abc"),
    ("beta", "0", "-3", "3,5"),
    ("delta", "8", "1e308", "NaN"),
    ("t_interval", "0.5", "100", "inf"),
    ("t_total", "1", "1e4", ""),
)


def _require_browser() -> None:
    problem = None
    if not (Path(CHROMIUM).exists() or shutil.which(CHROMIUM)):
        problem = f"no Chromium at {CHROMIUM} (apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            problem = "playwright is not installed (pip install -e '.[test]')"
    if problem is None:
        return
    if REQUIRED:
        pytest.fail(f"COGMAP_REQUIRE_BROWSER is set but {problem}")
    pytest.skip(problem)


def colour_pixels(png: bytes, rgb: tuple[int, int, int], tolerance: int = 40) -> int:
    """Pixels of a screenshot within ``tolerance`` of colour ``rgb``."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    target = np.array(rgb[::-1], dtype=np.int16)
    return int(np.count_nonzero(np.abs(image.astype(np.int16) - target).max(axis=2) < tolerance))


def control(page: Any, label: str) -> Any:
    """The input of the control labelled ``label`` in the panel."""
    return (
        page.locator("label", has_text=re.compile(f"^{re.escape(label)}$"))
        .locator("xpath=ancestor::div[contains(@class,'mantine-Flex-root')][1]")
        .locator("input")
        .first
    )


def choose(page: Any, label: str, option: str) -> None:
    """Pick ``option`` in the dropdown labelled ``label``."""
    control(page, label).click()
    page.get_by_role("option", name=option, exact=True).click()


def counters(page: Any, mode: str) -> tuple[str, ...]:
    """The page's vertices, edges, clusters and optimisations of map ``mode``."""
    return tuple(
        page.locator(f"#cogmap-{mode}-{key}").inner_text()
        for key in ("vertices", "edges", "clusters", "optimizations")
    )


def expected_counters(session: SlamSession, params: MapParams, mode: MapMode) -> tuple[str, ...]:
    cmap = session.rebuild(params)[mode]
    return (
        str(cmap.num_vertices),
        str(cmap.num_edges),
        str(len(cmap.clusters)),
        str(len(cmap.optimizations)),
    )


def wait_in_page(page: Any, mode: str, expected: tuple[str, ...], message: str) -> None:
    """Wait (polling in the page, every 5 ms) for map ``mode``'s counters and the message."""
    keys = ("vertices", "edges", "clusters", "optimizations")
    script = (
        "([ids, values, said]) => ids.every((id, k) => "
        "document.getElementById(id)?.textContent === values[k]) && "
        "(document.getElementById('cogmap-params-message')?.textContent ?? '').includes(said)"
    )
    ids = [f"cogmap-{mode}-{key}" for key in keys]
    page.wait_for_function(
        script, arg=[ids, list(expected), message], polling=5, timeout=TIMEOUT_MS
    )


#: How long the browser may take for anything but the HTML replay (software WebGL is slow).
WAIT_S = 30.0


def click_on(page: Any, view: Any, canvas: Any, world: np.ndarray) -> tuple[float, float]:
    """Click the canvas where the ground point ``world`` is drawn; return the pixel clicked.

    Three clicks around the middle of the canvas, and where their rays meet the ground (as the
    server receives them), give the map from pixels to the ground; the fourth click is on
    ``world``.
    """
    hits: list[np.ndarray] = []

    def record(event: Any) -> None:
        origin = np.asarray(event.ray_origin, float)
        direction = np.asarray(event.ray_direction, float)
        hits.append(origin - origin[2] / direction[2] * direction)

    view.client.scene.on_click()(record)
    box = canvas.bounding_box()
    pixels = [(0.3, 0.45), (0.45, 0.45), (0.3, 0.6)]
    for fx, fy in pixels:
        before = len(hits)
        page.mouse.click(box["x"] + fx * box["width"], box["y"] + fy * box["height"])
        until(lambda b=before: len(hits) > b, WAIT_S, "a click's ray")
    screen = np.array([[fx * box["width"], fy * box["height"], 1.0] for fx, fy in pixels])
    ground = np.array([h[:2] for h in hits])
    to_ground = np.linalg.solve(screen, ground)  # (3, 2): [px, py, 1] -> (x, y)
    x, y = np.linalg.solve(to_ground[:2].T, world[:2] - to_ground[2])
    view.select(None)  # forget what the calibration clicks selected
    before = len(hits)
    page.mouse.click(box["x"] + x, box["y"] + y)
    until(lambda: len(hits) > before, WAIT_S, "the click's ray")
    assert np.hypot(*(hits[-1][:2] - world[:2])) < 0.01, (hits, world)
    return float(x), float(y)


def camera_settled(view: Any) -> bool:
    """Whether the camera frames what the view shows, still, in the browser.

    The view has framed what it shows now, the browser has reported the pose it set, and the
    camera's position is the same in two reads 100 ms apart.
    """
    first = tuple(view.client.camera.position)
    time.sleep(0.1)
    return (
        view._framed == view.content_extent()
        and view._camera_acknowledged
        and tuple(view.client.camera.position) == first
    )


def close_notices(page: Any) -> None:
    """Close viser's "software WebGL" notice, which would cover part of the map."""
    for button in page.locator(".mantine-Notification-closeButton").all():
        button.click()


def test_the_page_in_chromium(
    short_bag: Path,
    reference: SlamSession,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    _require_browser()
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shots: list[Path] = []
    latencies: dict[str, float] = {}
    frames = reference.log.frames
    exports = tmp_path / "exports"
    with (
        support.running_app(short_bag, autoplay=False, export_dir=exports) as app,
        sync_playwright() as p,
    ):
        wait(app)
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 950})
            page.goto(f"http://127.0.0.1:{app.server.get_port()}", timeout=TIMEOUT_MS)
            status = page.locator("#cogmap-status")
            status.wait_for(timeout=TIMEOUT_MS)
            until(lambda: len(app.views) == 1, WAIT_S, "the tab's view")
            assert page.title() == "cogmap · compact cognitive map"
            close_notices(page)

            # ---- play at max speed to the end
            choose(page, "speed", "max")
            page.get_by_role("button", name="play", exact=True).click()
            page.wait_for_selector('#cogmap-status[data-state="ended"]', timeout=TIMEOUT_MS)
            assert page.locator("#cogmap-frames").inner_text() == f"{frames} / {frames}"
            compact = reference.maps[MapMode.COMPACT]
            assert page.locator("#cogmap-compact-vertices").inner_text() == str(
                compact.num_vertices
            )
            assert page.get_by_role("button", name="play", exact=True).is_visible()

            # ---- type every parameter: valid, out of range, garbage
            message = page.locator("#cogmap-params-message")
            params = MapParams()
            paper = expected_counters(reference, MapParams(), MapMode.COMPACT)
            for name, valid, outside, garbage in TYPED:
                spec = SPECS[name]
                box = control(page, f"{spec.label} =")
                params = MapParams()  # each parameter from the paper's values
                for typed in (valid, outside):
                    value = min(max(float(typed), spec.low), spec.high)
                    before = expected_counters(reference, params, MapMode.COMPACT)
                    params = params.with_changes(**{name: value})
                    expected = expected_counters(reference, params, MapMode.COMPACT)
                    said = (
                        f"{spec.label} = {typed}"
                        if typed == valid
                        else f"{spec.label} = {typed} is outside ["
                    )
                    box.click()
                    box.fill(typed)
                    started = time.perf_counter()
                    box.press("Enter")
                    wait_in_page(page, "compact", expected, said)
                    took = time.perf_counter() - started
                    if typed == valid:  # typing -> the counter changing
                        assert expected != before, f"{name} = {typed} changes no counter"
                        latencies[spec.label] = took
                    assert box.input_value() == format_value(value)
                    assert getattr(app.replay.params, name) == value
                box.click()
                box.fill(garbage)
                box.press("Enter")
                until(lambda: "refused" in message.inner_text(), WAIT_S, f"{name} refused")
                assert box.input_value() == format_value(getattr(params, name))
                assert app.replay.params == params
                page.get_by_role("button", name="reset to paper values").click()
                until(lambda: counters(page, "compact") == paper, WAIT_S, "paper values")

            # ---- switch maps, then two side by side
            view = next(iter(app.views.values()))
            canvas = page.locator("canvas").first
            choose(page, "map", "standard")
            until(lambda: view.state.shown == (MapMode.STANDARD,), WAIT_S, "standard")
            until(
                lambda: colour_pixels(canvas.screenshot(), MAP_COLORS[MapMode.STANDARD]) > 100,
                WAIT_S,
                "the standard map drawn",
            )
            control(page, "side by side").click()
            choose(page, "compare with", "compact")
            until(lambda: len(view.state.shown) == 2, WAIT_S, "side by side")
            until(
                lambda: colour_pixels(canvas.screenshot(), MAP_COLORS[MapMode.COMPACT]) > 50,
                WAIT_S,
                "the compact map beside",
            )

            # ---- click a vertex of the compact map (drawn beside the standard one)
            choose(page, "map", "compact")
            choose(page, "compare with", "standard")
            until(lambda: view.state.shown == (MapMode.COMPACT, MapMode.STANDARD), WAIT_S)
            until(lambda: camera_settled(view), WAIT_S, "the camera framing the two maps")
            snap = app.replay.session.maps[MapMode.COMPACT].snapshot()
            k = snap.vertex_ids.shape[0] // 3
            target = np.array([snap.poses[k, 0], snap.poses[k, 1], 0.0])
            x, y = click_on(page, view, canvas, target)
            inspect = page.locator("#cogmap-inspect")
            until(lambda: inspect.get_attribute("data-kind") == "vertex", WAIT_S, "a pick")
            assert f"vertex id {snap.vertex_ids[k]}" in " ".join(inspect.inner_text().split())

            # ---- pin the compact map, change delta, compare
            page.get_by_role("button", name="pin the shown map").click()
            delta = control(page, "δ =")
            delta.click()
            delta.fill("8")
            delta.press("Enter")
            changed = expected_counters(reference, MapParams(delta=8.0), MapMode.COMPACT)
            until(lambda: counters(page, "compact") == changed, WAIT_S, "delta = 8")
            live = page.locator("#cogmap-compare-live-vertices")
            until(lambda: live.inner_text() == changed[0], WAIT_S, "the comparison")
            pinned = page.locator("#cogmap-compare-pinned-vertices").inner_text()
            assert pinned == str(compact.num_vertices) != changed[0]
            until(
                lambda: colour_pixels(canvas.screenshot(), PINNED_COLOR, 45) > 20,
                WAIT_S,
                "the pinned map drawn",
            )
            page.screenshot(path=str(ARTIFACTS / "browser-compare.png"))
            shots.append(ARTIFACTS / "browser-compare.png")

            # ---- a second tab: a view of its own, space plays and pauses
            second = browser.new_page(viewport={"width": 1200, "height": 900})
            second.goto(f"http://127.0.0.1:{app.server.get_port()}", timeout=TIMEOUT_MS)
            second.locator("#cogmap-status").wait_for(timeout=TIMEOUT_MS)
            until(lambda: len(app.views) == 2, WAIT_S, "the second tab's view")
            close_notices(second)
            other = next(v for v in app.views.values() if v is not view)
            assert other.state.shown == (MapMode.COMPACT,) and other.pinned is None
            assert control(second, "map").input_value() == "compact"
            assert not control(second, "side by side").is_checked()
            assert control(page, "side by side").is_checked()  # the first tab kept its view
            assert control(second, "δ =").input_value() == "8"  # parameters are shared
            choose(second, "speed", "1x")  # shared: the first tab shows it too
            until(lambda: control(page, "speed").input_value() == "1x", WAIT_S, "shared speed")
            second.mouse.click(40, 40)  # focus the page (not a box or a button)
            second.keyboard.press("Space")  # at the end: plays again from the start
            second.wait_for_selector('#cogmap-status[data-state="playing"]', timeout=TIMEOUT_MS)
            second.keyboard.press("Space")
            second.wait_for_selector('#cogmap-status[data-state="paused"]', timeout=TIMEOUT_MS)
            assert not app.replay.playing and 0 < app.replay.cursor < frames
            second.screenshot(path=str(ARTIFACTS / "browser-second-tab.png"))
            shots.append(ARTIFACTS / "browser-second-tab.png")

            # ---- exports: summary.json to the browser, an HTML replay in the export folder
            # on the server and to the browser (a name only: no server path can be typed)
            with page.expect_download(timeout=TIMEOUT_MS) as download:
                page.get_by_role("button", name="download summary.json").click()
            summary = json.loads(Path(download.value.path()).read_text())
            assert summary["frames"] == app.replay.cursor
            assert summary["params"]["delta"] == 8.0
            replay_box = control(page, "replay name")
            replay_box.click()
            replay_box.fill("../my replay.html")
            replay_box.press("Enter")
            until(lambda: app.replay_path.value == "../my replay.html", WAIT_S, "the name")
            with page.expect_download(timeout=120_000) as download:
                page.get_by_role("button", name="save HTML replay").click()
            export = page.locator("#cogmap-export")
            until(lambda: "saved the HTML replay" in export.inner_text(), 120, "the replay")
            assert "as my_replay.html in the export folder" in export.inner_text()
            out = exports / "my_replay.html"
            assert sorted(p.name for p in exports.iterdir()) == ["my_replay.html"]
            umask = os.umask(0)
            os.umask(umask)
            assert out.stat().st_mode & 0o777 == 0o666 & ~umask
            assert "cogmap replay" in out.read_text()[:20000]
            assert download.value.suggested_filename == "my_replay.html"
            assert Path(download.value.path()).read_bytes() == out.read_bytes()
            page.screenshot(path=str(ARTIFACTS / "browser-final.png"))
            shots.append(ARTIFACTS / "browser-final.png")
        finally:
            browser.close()
    with capsys.disabled():
        print("\ntyped value -> counter changed in Chromium (short bag, compact map):")
        for label, took in latencies.items():
            print(f"  {label:>10}: {took * 1000:6.0f} ms")
        print(f"  median {statistics.median(latencies.values()) * 1000:.0f} ms")
        print("browser screenshots: " + ", ".join(str(s) for s in shots))


def test_chromium_keeps_other_origins_out_and_the_token_holder_in(
    short_bag: Path, tmp_path: Path
) -> None:
    """Issue 24: a page of another port opens no websocket; a tab with the token's URL works."""
    _require_browser()
    import functools
    import http.server
    import threading

    import viser
    from playwright.sync_api import sync_playwright

    from app.server.access import AccessPolicy
    from app.server.app import CogmapApp

    token = "t" * 32
    server = support.make_server(AccessPolicy(token=token))
    app = CogmapApp(server, short_bag, autoplay=False, export_dir=tmp_path / "exports")
    port = server.get_port()
    (tmp_path / "evil.html").write_text(
        "<script>window.result = 'pending';"
        f"const ws = new WebSocket('ws://127.0.0.1:{port}/?token={token}', "
        f"['viser-v{viser.__version__}']);"
        "ws.onopen = () => { window.result = 'open'; };"
        "ws.onerror = () => { window.result = 'refused'; };</script>"
    )
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    evil = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=evil.serve_forever, daemon=True).start()
    try:
        app.start()
        wait(app)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            try:
                page = browser.new_page()
                for host in ("127.0.0.1", "localhost"):  # another port; another host name
                    page.goto(f"http://{host}:{evil.server_port}/evil.html", timeout=TIMEOUT_MS)
                    page.wait_for_function("window.result !== 'pending'", timeout=TIMEOUT_MS)
                    assert page.evaluate("window.result") == "refused"
                assert app.server.get_clients() == {}
                page.goto(f"http://127.0.0.1:{port}/", timeout=TIMEOUT_MS)
                assert "needs its token" in page.content()
                page.goto(f"http://127.0.0.1:{port}/?token={token}", timeout=TIMEOUT_MS)
                page.locator("#cogmap-status").wait_for(timeout=TIMEOUT_MS)
                until(lambda: len(app.views) == 1, WAIT_S, "the tab's view")
                page.get_by_role("button", name="play", exact=True).click()
                until(lambda: app.replay.playing, WAIT_S, "play from the tab")
            finally:
                browser.close()
    finally:
        evil.shutdown()
        app.stop()
        server.stop()
