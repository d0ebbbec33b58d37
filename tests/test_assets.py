"""The page's assets are found in the source tree, in an installed copy, or in ./static."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from app.server import assets

ROOT = Path(__file__).resolve().parents[1]


def test_the_source_tree_assets_come_first() -> None:
    assert assets.find_asset_dir() == ROOT / "static"
    assert "g(d, θ) = (1 + α·d)(1 + β·|θ|)" in assets.read_asset("help.md")


def test_an_installed_copy_is_found_outside_the_source_tree(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    installed = tmp_path / "prefix" / assets.INSTALLED_ASSETS
    installed.mkdir(parents=True)
    (installed / "cogmap.js").write_text("// installed\n")
    monkeypatch.setattr(assets, "find_static_dir", lambda: tmp_path / "nowhere" / "static")
    monkeypatch.setattr(assets.sysconfig, "get_path", lambda name: str(tmp_path / "prefix"))
    assert assets.find_asset_dir() == installed
    # nothing installed either: ./static (the page then works without its assets)
    (installed / "cogmap.js").unlink()
    assert assets.find_asset_dir() == tmp_path / "nowhere" / "static"


def test_every_asset_is_installed_with_the_package() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    listed = config["tool"]["setuptools"]["data-files"][str(assets.INSTALLED_ASSETS)]
    shipped = sorted(
        p.name
        for p in (ROOT / "static").iterdir()
        if p.is_file() and not p.name.startswith(".") and p.name != "README.md"
    )
    assert sorted(Path(f).name for f in listed) == shipped
    assert all((ROOT / f).is_file() for f in listed)
