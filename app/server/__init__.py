"""The live web app (``cogmap serve``): a viser page that replays a bag and tunes the maps live.

- :mod:`app.server.replay` -- the worker thread owning the SLAM session (playback; its rebuilds
  in :mod:`app.server.replay_rebuilds`, its state in :mod:`app.server.replay_state`).
- :mod:`app.server.rebuild` -- rebuilding maps for new parameters (worker processes, cache).
- :mod:`app.server.preview` -- what a slow rebuild shows at once, before its exact map.
- :mod:`app.server.figures_worker` -- the maps' accuracy figures, on a thread of their own.
- :mod:`app.server.scene` -- incremental streaming of the maps into the 3-D scene
  (:mod:`~app.server.map_layer`, :mod:`~app.server.scene_nodes`, :mod:`~app.server.scene_style`).
- :mod:`app.server.view` -- each viewer's own view (map, layers, camera, inspection, pin, route).
- :mod:`app.server.panels` -- the page's panels, one builder each.
- :mod:`app.server.app` -- the page: composes the panels, wires them to the workers.
- :mod:`app.server.export` -- g2o, summary.json, sizes.csv and the self-contained HTML replay.

Nothing is imported here, so that a rebuild worker process (``python -m app.server.rebuild``)
loads only what it needs.
"""

from __future__ import annotations

from typing import Any

__all__ = ["CogmapApp", "PlaybackState", "Replay"]


def __getattr__(name: str) -> Any:
    """``CogmapApp``, ``PlaybackState`` and ``Replay``, imported when first used."""
    if name == "CogmapApp":
        from app.server.app import CogmapApp

        return CogmapApp
    if name in ("PlaybackState", "Replay"):
        from app.server import replay

        return getattr(replay, name)
    raise AttributeError(name)
