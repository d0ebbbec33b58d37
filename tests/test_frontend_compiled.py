"""The front end's compiled loops: when they are used, and that they compute the numpy code's."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from cogmap_core.datasets import MazeConfig, generate_maze_bag, open_bag
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.frames import Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig
from cogmap_core.frontend import compiled as compiled_module
from cogmap_core.frontend.compiled import ENV_SWITCH, kernels, prefer_compiled

pytest.importorskip("numba")


@pytest.fixture
def preference() -> Iterator[None]:
    """Restore the process's preference after a test changes it."""
    saved = compiled_module._PREFERRED
    yield
    prefer_compiled(saved)


def test_the_switch_decides_and_unset_the_program_s_preference(
    preference: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    prefer_compiled(True)
    assert kernels() is not None
    prefer_compiled(False)  # what `cogmap run` says
    assert kernels() is None
    assert FrontEnd(FrontEndConfig()).local_view._compiled is None
    monkeypatch.setenv(ENV_SWITCH, "1")
    assert kernels() is not None  # the switch overrides the preference
    assert FrontEnd(FrontEndConfig()).local_view._compiled is not None
    monkeypatch.setenv(ENV_SWITCH, "0")
    prefer_compiled(True)
    assert kernels() is None


def test_cogmap_run_prefers_the_numpy_code(
    preference: None, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from app.cli import main

    monkeypatch.delenv(ENV_SWITCH, raising=False)
    prefer_compiled(True)
    assert main(["run", str(tmp_path / "missing.bag"), "--out", str(tmp_path / "r")]) == 2
    assert compiled_module._PREFERRED is False


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Frame], FrontEndConfig]:
    bag = tmp_path_factory.mktemp("bag") / "figure8.bag"
    generate_maze_bag(bag, MazeConfig(layout="figure_eight", laps=1, seed=5), workers=2)
    with open_bag(bag, image_scale=1) as reader:
        return list(reader.frames()), frontend_config_for(bag)


def _outputs(
    frames: list[Frame], config: FrontEndConfig, compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> list[Any]:
    monkeypatch.setenv(ENV_SWITCH, "1" if compiled else "0")
    frontend = FrontEnd(config)
    assert (frontend.local_view._compiled is not None) is compiled
    assert (frontend.pose_cells.network._compiled is not None) is compiled
    outputs: list[Any] = []
    for frame in frames:
        events = frontend.process(frame)
        view = frontend.last_view
        assert view is not None
        outputs.append((view.template_id, view.offset, view.error, repr(events)))
        outputs.append(frontend.pose_cell_peak)
    return outputs


@pytest.mark.parametrize("settings", ["irat", "profile"])
def test_the_compiled_loops_give_the_numpy_code_s_outputs_frame_by_frame(
    frames: tuple[list[Frame], FrontEndConfig], settings: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    images, profile = frames
    config = FrontEndConfig() if settings == "irat" else profile
    numpy_outputs = _outputs(images, config, False, monkeypatch)
    compiled_outputs = _outputs(images, config, True, monkeypatch)
    assert len(numpy_outputs) == 2 * len(images) > 1000
    assert compiled_outputs == numpy_outputs
    templates = {output[0] for output in numpy_outputs[::2]}
    assert len(templates) > 20  # templates were made and matched: the search was exercised
