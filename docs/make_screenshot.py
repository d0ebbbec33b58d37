"""Make the screenshots of ``docs/web-app.md``: the page in its final states.

    python docs/make_screenshot.py [BAG] [--log LOG] [--out-dir docs]

Replays the bag (default: the built-in dataset) to its end at full speed, opens the page in
Chromium and saves:

- ``web-app.png``: the compact map over the aligned ground truth (the default view: the plan
  view, the metric grid with its scale bar);
- ``web-app-side-by-side.png``: the standard map with the compact map beside it, each named;
- ``web-app-pose-cells.png``: the network behind the map -- the current view beside the view
  template it matched, and the pose-cell activity with its peak;
- ``web-app-pinned.png``: the compact map at the paper's values pinned under the live compact
  map at δ = 16 (the sweep's best setting), with the two parameter sets compared in the panel;
- ``web-app-error.png``: the standard map's edges coloured by their residual (whitened, at the
  map's poses) over the metric grid;

then replays the log (default: TUC's Lecture Hall, ``../shared/real/tuc/Lecture_Hall_Input.txt``
beside the repository; skipped when absent) and saves ``web-app-lecture-hall.png``: its
standard and compact maps side by side over a 40 m hall, the false loop closures in red.

Needs Chromium at /usr/bin/chromium and playwright (``pip install -e '.[test]'``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import viser  # noqa: E402

from app.cli_common import resolve_bag  # noqa: E402
from app.server.app import CogmapApp  # noqa: E402
from app.server.view import ClientView  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402
from cogmap_core.sources.detect import KINDS  # noqa: E402
from tests.test_browser import choose, close_notices, control  # noqa: E402
from tests.test_server_support import CHROMIUM_ARGS  # noqa: E402

SETTLE_S = 3.0  # for the browser to draw what the server sent
#: TUC's Lecture Hall, where the repository's neighbours keep it (never copied into it).
LECTURE_HALL = Path(__file__).resolve().parents[2] / "shared/real/tuc/Lecture_Hall_Input.txt"


def _wait(condition: Any, what: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {what}")
        time.sleep(0.1)


def main() -> int:
    """Replay, open the page, save the screenshots."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", default=None, help="bag (default: built-in dataset)")
    parser.add_argument("--out-dir", default=str(Path(__file__).parent))
    parser.add_argument(
        "--log",
        default=str(LECTURE_HALL),
        help="a log of odometry and place recognition for web-app-lecture-hall.png",
    )
    parser.add_argument("--width", type=int, default=1600)
    parser.add_argument("--height", type=int, default=1000)
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    out = Path(args.out_dir)
    bag = resolve_bag(args.bag)  # default: the built-in dataset
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8093, verbose=False)
    app = CogmapApp(server, bag, speed=math.inf)
    app.start()
    if not app.wait_idle(3600):
        raise SystemExit("the replay did not finish")
    print(f"replayed {app.replay.cursor} frames: {app.replay.state.value} {app.replay.message}")
    written: list[Path] = []

    def shot(page: Any, name: str) -> None:
        _wait(lambda: app.wait_idle(60), "the page to catch up")
        time.sleep(SETTLE_S)
        path = out / name
        page.screenshot(path=str(path))
        written.append(path)

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": args.width, "height": args.height})
        page.goto(f"http://127.0.0.1:{server.get_port()}")
        page.locator("#cogmap-compact-vertices").wait_for(timeout=30_000)
        _wait(lambda: len(app.views) == 1, "the tab's view")
        view: ClientView = next(iter(app.views.values()))
        time.sleep(1.0)
        close_notices(page)
        shot(page, "web-app.png")

        page.evaluate("document.getElementById('cogmap-network').scrollIntoView()")
        shot(page, "web-app-pose-cells.png")
        page.evaluate("document.getElementById('cogmap-status').scrollIntoView()")

        choose(page, "map", "standard")
        control(page, "side by side").click()
        choose(page, "compare with", "compact")
        _wait(lambda: view.state.shown == (MapMode.STANDARD, MapMode.COMPACT), "side by side")
        shot(page, "web-app-side-by-side.png")

        control(page, "side by side").click()
        choose(page, "colour edges by", "error (residual)")
        _wait(lambda: view.state.shown == (MapMode.STANDARD,), "the standard map alone")
        shot(page, "web-app-error.png")
        choose(page, "colour edges by", "loop closures by cluster")

        choose(page, "map", "compact")
        _wait(lambda: view.state.shown == (MapMode.COMPACT,), "the compact map")
        page.get_by_role("button", name="pin the shown map").click()
        _wait(lambda: view.pinned is not None, "the pin")
        choose(page, "pinned map", "under")
        delta = control(page, "δ =")
        delta.click()
        delta.fill("16")
        delta.press("Enter")
        _wait(lambda: app.replay.params.delta == 16.0, "δ = 16")
        _wait(lambda: app.wait_idle(60), "the rebuild")
        live = page.locator("#cogmap-compare-live-vertices")
        _wait(lambda: live.count() == 1 and live.inner_text() != "", "the comparison")
        for _ in range(20):  # the panel's HTML is replaced as figures arrive: try again
            try:
                live.scroll_into_view_if_needed(timeout=2_000)
                break
            except Exception:
                time.sleep(0.5)
        shot(page, "web-app-pinned.png")
        browser.close()
    app.stop()
    server.stop()
    log = Path(args.log)
    if log.is_file():
        written.append(_log_screenshot(log, out / "web-app-lecture-hall.png", args))
    else:
        print(f"no {log}: web-app-lecture-hall.png not made")
    for path in written:
        print(f"wrote {path}")
    return 0


def _log_screenshot(log: Path, path: Path, args: argparse.Namespace) -> Path:
    """The log's standard and compact maps side by side, at the end of the log."""
    from playwright.sync_api import sync_playwright

    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8094, verbose=False)
    kind = KINDS["tuc"]
    app = CogmapApp(server, log, speed=math.inf, params=kind.map_params, defaults=kind.map_params)
    app.start()
    if not app.wait_idle(3600):
        raise SystemExit("the log's replay did not finish")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": args.width, "height": args.height})
        page.goto(f"http://127.0.0.1:{server.get_port()}")
        page.locator("#cogmap-compact-vertices").wait_for(timeout=30_000)
        _wait(lambda: len(app.views) == 1, "the tab's view")
        view: ClientView = next(iter(app.views.values()))
        time.sleep(1.0)
        close_notices(page)
        choose(page, "map", "standard")
        control(page, "side by side").click()
        choose(page, "compare with", "compact")
        _wait(lambda: view.state.shown == (MapMode.STANDARD, MapMode.COMPACT), "side by side")
        _wait(lambda: app.wait_idle(60), "the page to catch up")
        page.evaluate("document.getElementById('cogmap-counters').scrollIntoView()")
        time.sleep(SETTLE_S)
        page.screenshot(path=str(path))
        browser.close()
    app.stop()
    server.stop()
    return path


if __name__ == "__main__":
    sys.exit(main())
