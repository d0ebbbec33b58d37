"""Re-create the recorded front-end event streams in this folder (run from the repository root).

``python tests/data/make_event_recordings.py`` generates small maze bags in a temporary folder,
runs cogmap's front end over them and saves what it emitted, with the ground truth per frame, as
event files (:mod:`cogmap_core.event_file`):

- ``figure_eight_3laps.events.npz``: 3 laps of the built-in ``figure_eight`` layout (seed 1).
- ``junction_dead_end_2laps.events.npz``: 2 laps of ``junction_dead_end`` (seed 3).

Map tests replay these: they are the event patterns the front end really produces (revisits come
as link + set current, with the occasional new vertex proposed on known ground), not hand-written
scripts. Re-create them when the front end's output changes on purpose.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from cogmap_core.datasets import open_bag
from cogmap_core.datasets.generator import MazeConfig, generate_maze_bag
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.event_file import save_event_file
from cogmap_core.slam import SlamSession

HERE = Path(__file__).parent
RECORDINGS = {
    "figure_eight_3laps": MazeConfig(layout="figure_eight", laps=3, seed=1),
    "junction_dead_end_2laps": MazeConfig(layout="junction_dead_end", laps=2, seed=3),
}


def record(name: str, config: MazeConfig) -> Path:
    """Generate the bag of ``config``, run the front end, save its events as ``name``."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / f"{name}.bag"
        generate_maze_bag(bag, config)
        frontend = frontend_config_for(bag)
        session = SlamSession(frontend_config=frontend, modes=())
        with open_bag(bag, image_scale=1) as reader:  # full size, as cogmap run
            for frame in reader.frames():
                session.process(frame)
        source = f"{config.layout}, {config.laps} laps, seed {config.seed}"
        recording = session.log.recording(source)
        recording.frontend = frontend.to_dict()
        return save_event_file(HERE / f"{name}.events.npz", recording)


if __name__ == "__main__":
    for name, config in RECORDINGS.items():
        path = record(name, config)
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
