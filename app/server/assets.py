"""The page's assets in ``static/``: styles, script, logo, help text, the replay caption.

viser builds the page from its own client; the app adds its styles and script through one HTML
element at the top of the panel (:func:`head_html`). Browsers do not run ``<script>`` elements
inserted as HTML, so the script is started by the ``onerror`` handler of an image that cannot
load -- the usual way to run code from inserted HTML. A missing asset leaves the page working
without it (and says so in the server's log).
"""

from __future__ import annotations

import base64
import html
import logging
import sys
import sysconfig
import urllib.parse
from functools import cache
from pathlib import Path

log = logging.getLogger(__name__)

TITLE = "cogmap · compact cognitive map"
#: Where ``pip install .`` puts ``static/``'s files (``[tool.setuptools.data-files]``).
INSTALLED_ASSETS = Path("share") / "cogmap" / "static"


def find_static_dir() -> Path:
    """``static/`` of the source tree when running from it, else ``./static``."""
    source = Path(__file__).resolve().parents[2] / "static"
    return source if source.is_dir() else Path("static")


def find_asset_dir() -> Path:
    """The assets: ``static/`` of the source tree, else the installed copy, else ``./static``."""
    source = find_static_dir()
    if (source / "cogmap.js").is_file():
        return source
    for prefix in (sysconfig.get_path("data"), sys.prefix):
        installed = Path(prefix) / INSTALLED_ASSETS
        if (installed / "cogmap.js").is_file():
            return installed
    return source


@cache
def read_asset(name: str, static_dir: Path | None = None) -> str:
    """The text of ``static/<name>`` ("" when it is missing)."""
    base = static_dir if static_dir is not None else find_asset_dir()
    path = base / name
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        log.warning("web-app asset %s not found (%s); the page works without it", path, exc)
        return ""


def logo_svg(static_dir: Path | None = None) -> str:
    """The logo as inline SVG."""
    return read_asset("logo.svg", static_dir)


def logo_data_url(static_dir: Path | None = None) -> str:
    """The logo as a ``data:`` URL (the tab's icon)."""
    svg = logo_svg(static_dir)
    return "data:image/svg+xml," + urllib.parse.quote(svg) if svg else ""


def head_html(static_dir: Path | None = None) -> str:
    """The element at the top of the panel: styles, the page's script, logo and title."""
    css = read_asset("cogmap.css", static_dir)
    script = read_asset("cogmap.js", static_dir)
    script = script.replace("__COGMAP_TITLE__", TITLE).replace(
        "__COGMAP_ICON__", logo_data_url(static_dir)
    )
    encoded = base64.b64encode(script.encode()).decode()
    runner = (
        f'<img alt="" style="display:none" src="data:image/gif;base64,AA==" '
        f"onerror=\"eval(new TextDecoder().decode(Uint8Array.from(atob('{encoded}'), "
        f'c => c.charCodeAt(0))))">'
        if script
        else ""
    )
    return (
        f"<style>{css}</style>{runner}"
        f'<div class="cogmap-head" id="cogmap-head">{logo_svg(static_dir)}'
        f"<span><b>cogmap</b> · {html.escape(TITLE.split(' · ', 1)[1])}</span></div>"
    )


def help_markdown(static_dir: Path | None = None) -> str:
    """The help block's text."""
    return read_asset("help.md", static_dir) or "(help text not found: static/help.md)"
