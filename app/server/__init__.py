"""The live web app (``cogmap serve``): a viser page that replays a bag and tunes the maps live.

- :mod:`app.server.replay` -- the worker thread owning the SLAM session (playback, rebuilds).
- :mod:`app.server.scene` -- incremental streaming of the maps into the 3-D scene.
- :mod:`app.server.app` -- the page: panels, controls, counters, chart, log, export buttons.
- :mod:`app.server.export` -- g2o, summary.json, sizes.csv and the self-contained HTML replay.
"""

from app.server.app import CogmapApp
from app.server.replay import PlaybackState, Replay

__all__ = ["CogmapApp", "PlaybackState", "Replay"]
