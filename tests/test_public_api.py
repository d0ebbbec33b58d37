"""The public API: ``cogmap_core``'s names, and the examples of ``docs/api.md``, run as written."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import cogmap_core

ROOT = Path(__file__).resolve().parents[1]
API_DOC = ROOT / "docs" / "api.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.M | re.S)


def test_every_public_name_is_its_module_s_own():
    assert set(cogmap_core.__all__) == {*cogmap_core._PUBLIC, "__version__"}
    for name, module in cogmap_core._PUBLIC.items():
        assert getattr(cogmap_core, name) is getattr(importlib.import_module(module), name)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        cogmap_core.nothing_here  # noqa: B018
    namespace: dict[str, object] = {}
    exec("from cogmap_core import *", namespace)
    assert {n for n in namespace if not n.startswith("__")} == set(cogmap_core._PUBLIC)


def test_importing_the_package_loads_no_module_of_it():
    code = (
        "import sys, cogmap_core\n"
        "from cogmap_core import __version__, errors\n"
        "print(sorted(m for m in sys.modules if m.startswith('cogmap_core')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "['cogmap_core', 'cogmap_core.errors']"


def test_the_doc_names_every_public_name():
    text = API_DOC.read_text(encoding="utf-8")
    for name in cogmap_core._PUBLIC:
        assert f"`{name}`" in text, name


@pytest.mark.parametrize("number", [0, 1])
def test_the_doc_examples_run(number: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys):
    blocks = _python_blocks(API_DOC.read_text(encoding="utf-8"))
    assert len(blocks) == 2
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the example's files go there
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[number], f"{API_DOC}:example {number + 1}", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in printed[:3]] == [
        "standard",
        "scene_integration",
        "compact",
    ]
    if number == 0:
        assert len(list(tmp_path.glob("*/compact.g2o"))) == 1
