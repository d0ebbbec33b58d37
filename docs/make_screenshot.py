"""Make ``docs/web-app.png``: the page after a full replay of the default dataset (compact map).

    python docs/make_screenshot.py [BAG] [--out docs/web-app.png]

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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import viser  # noqa: E402

from app.cli_common import resolve_bag  # noqa: E402
from app.server.app import CogmapApp  # noqa: E402
from tests.test_server_support import CHROMIUM_ARGS  # noqa: E402


def main() -> int:
    """Replay, open the page, save the screenshot."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", default=None, help="bag (default: built-in dataset)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "web-app.png"))
    parser.add_argument("--width", type=int, default=1600)
    parser.add_argument("--height", type=int, default=1000)
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    bag = resolve_bag(args.bag)  # default: the built-in dataset
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8093, verbose=False)
    app = CogmapApp(server, bag, speed=math.inf)
    app.start()
    if not app.replay.wait_idle(3600):
        raise SystemExit("the replay did not finish")
    print(f"replayed {app.replay.cursor} frames: {app.replay.state.value} {app.replay.message}")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": args.width, "height": args.height})
        page.goto(f"http://127.0.0.1:{server.get_port()}")
        page.locator("#cogmap-compact-vertices").wait_for(timeout=30_000)
        time.sleep(3.0)
        # close viser's "software WebGL" notice, which would cover the map
        for button in page.locator(".mantine-Notification-closeButton").all():
            button.click()
        time.sleep(1.0)
        page.screenshot(path=args.out)
        browser.close()
    app.stop()
    server.stop()
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
