"""The page in a real browser: Debian's Chromium driven by playwright.

Opens the page of a server that replayed a short bag, waits for the compact map to be drawn,
types a new delta into the number box beside the delta slider and checks that the vertex counter
shows the count ``SlamSession.rebuild`` gives for it and that the drawn map changed. A screenshot
is saved as an artifact (its path is printed).

Skipped when Chromium is not installed, unless ``COGMAP_REQUIRE_BROWSER`` is set (CI sets it):
then a missing browser is a failure.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.server.scene import MAP_COLORS
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.slam import SlamSession
from tests import test_server_support as support

short_bag = support.short_bag  # session fixtures
reference = support.reference

CHROMIUM = os.environ.get("COGMAP_CHROMIUM", "/usr/bin/chromium")
REQUIRED = bool(os.environ.get("COGMAP_REQUIRE_BROWSER"))
ARGS = support.CHROMIUM_ARGS
ARTIFACTS = Path(
    os.environ.get("COGMAP_ARTIFACTS", Path(tempfile.gettempdir()) / "cogmap-artifacts")
)

pytestmark = pytest.mark.browser


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


def map_pixels(png: bytes) -> int:
    """Pixels of the canvas screenshot drawn in the compact map's colour."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    r, g, b = MAP_COLORS[MapMode.COMPACT]
    target = np.array([b, g, r], dtype=np.int16)
    return int(np.count_nonzero(np.abs(image.astype(np.int16) - target).max(axis=2) < 40))


def test_page_shows_the_map_and_the_delta_slider_rebuilds_it(
    short_bag: Path, reference: SlamSession, capsys: pytest.CaptureFixture[str]
) -> None:
    _require_browser()
    from playwright.sync_api import sync_playwright

    expected = reference.rebuild(MapParams(delta=8.0))[MapMode.COMPACT].num_vertices
    before = reference.maps[MapMode.COMPACT].num_vertices
    assert expected != before
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shot = ARTIFACTS / "browser-delta.png"
    with support.running_app(short_bag) as app, sync_playwright() as p:
        assert app.replay.wait_idle(60)
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(f"http://127.0.0.1:{app.server.get_port()}", timeout=30_000)
            vertices = page.locator("#cogmap-compact-vertices")
            vertices.wait_for(timeout=30_000)
            assert vertices.inner_text() == str(before)
            canvas = page.locator("canvas").first
            drawn = 0
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:  # the map appears (software WebGL)
                first = canvas.screenshot()
                drawn = map_pixels(first)
                if drawn > 50:
                    break
                time.sleep(0.5)
            assert drawn > 50, "the compact map was not drawn"

            # the number box beside the slider labelled δ
            slider_id = page.locator("label", has_text=re.compile("^δ$")).get_attribute("for")
            assert slider_id
            box = (
                page.locator(f'[id="{slider_id}"]').locator("xpath=..").locator("input[type=text]")
            )
            box.click()
            box.fill("8")
            box.press("Enter")
            page.wait_for_function(
                f"document.querySelector('#cogmap-compact-vertices')?.textContent === '{expected}'",
                timeout=30_000,
            )
            assert app.replay.params.delta == 8.0
            changed = False
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline:  # the drawn map changes
                after = canvas.screenshot()
                a = cv2.imdecode(np.frombuffer(first, np.uint8), cv2.IMREAD_GRAYSCALE)
                b = cv2.imdecode(np.frombuffer(after, np.uint8), cv2.IMREAD_GRAYSCALE)
                if a.shape == b.shape and np.count_nonzero(cv2.absdiff(a, b) > 30) > 50:
                    changed = True
                    break
                time.sleep(0.5)
            page.screenshot(path=str(shot))
            assert changed, "the scene did not change after the slider moved"
        finally:
            browser.close()
    with capsys.disabled():
        print(f"\nbrowser screenshot: {shot}")
