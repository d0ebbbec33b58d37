"""The Dockerfile (no Docker engine here): valid instructions, an unprivileged user, the token.

Issue 24: the image served on every interface as root, with no token. It must run as a user of
its own, keep the token (no ``--no-token``), list bags and save replays only in its own folders,
and document publishing the port on loopback.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEYWORDS = {"FROM", "ENV", "RUN", "WORKDIR", "COPY", "USER", "EXPOSE", "CMD", "ARG", "LABEL"}


def instructions() -> list[tuple[str, str]]:
    """(keyword, arguments) of each instruction, continuation lines joined."""
    out: list[tuple[str, str]] = []
    pending = ""
    for line in (ROOT / "Dockerfile").read_text().splitlines():
        if not pending and (not line.strip() or line.lstrip().startswith("#")):
            continue
        pending += line.rstrip()
        if pending.endswith("\\"):
            pending = pending[:-1] + " "
            continue
        keyword, _, rest = pending.strip().partition(" ")
        out.append((keyword, rest.strip()))
        pending = ""
    assert not pending, "a continuation line at the end"
    return out


def test_the_image_runs_as_an_unprivileged_user_and_keeps_the_token() -> None:
    steps = instructions()
    assert {k for k, _ in steps} <= KEYWORDS
    assert steps[0][0] == "FROM"
    for keyword, rest in steps:
        if keyword == "COPY":
            *sources, _ = rest.split()
            assert all((ROOT / s).exists() for s in sources), rest
    users = [rest for k, rest in steps if k == "USER"]
    assert users and users[-1].split(":")[0] not in ("root", "0")
    keywords = [k for k, _ in steps]
    assert keywords.index("USER") < keywords.index("CMD")
    assert keywords.index("RUN", keywords.index("USER")) > 0  # the dataset made as that user
    cmd = json.loads(dict(steps)["CMD"])
    assert cmd == [
        "cogmap", "serve", "--host", "0.0.0.0", "--port", "8080",
        "--data-dir", "/var/cache/cogmap", "--data-dir", "/data", "--export-dir", "/exports",
    ]  # fmt: skip
    assert "--no-token" not in cmd
    header = (ROOT / "Dockerfile").read_text().split("FROM", 1)[0]
    assert "docker run --rm -p 127.0.0.1:8080:8080 cogmap" in header
    assert re.search(r"useradd --system --uid 10001", (ROOT / "Dockerfile").read_text())
