"""Where a session's frames come from: camera bags, or logs of odometry and place recognition.

- :mod:`cogmap_core.sources.odometry_log` -- a log of wheel odometry and place-recognition loop
  candidates (any system: NetVLAD, sequence matching, ...) turned into map events directly, so
  the compact cognitive map serves as the back end of someone else's front end.
- :mod:`cogmap_core.sources.tuc` (the TUC SLAM dataset's text format) and
  :mod:`cogmap_core.sources.odometry_csv` (plain CSV files) -- the log formats' readers, one file
  each, on :mod:`cogmap_core.sources.log_text`'s fast line reader.
- :mod:`cogmap_core.sources.detect` -- which kind of file a path is (``bag``, ``tuc``, ``csv``)
  and :func:`~cogmap_core.sources.detect.open_source`, one reader interface for all of them.

The camera readers (bags, videos, image folders) live in :mod:`cogmap_core.datasets`; this
package uses them and they never import it back.
"""
