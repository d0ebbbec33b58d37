"""Where a session's frames come from: camera bags, or logs of odometry and place recognition.

- :mod:`cogmap_core.sources.odometry_log` -- a log of wheel odometry and place-recognition loop
  candidates (any system: NetVLAD, sequence matching, ...) turned into map events directly, so
  the compact cognitive map serves as the back end of someone else's front end.
- :mod:`cogmap_core.sources.detect` -- which kind of file a path is (``bag``, ``tuc``, ``csv``)
  and :func:`~cogmap_core.sources.detect.open_source`, one reader interface for all of them.

The format readers live beside the bag reader, one file each:
:mod:`cogmap_core.datasets.tuc` (the TUC SLAM dataset's text format) and
:mod:`cogmap_core.datasets.odometry_csv` (plain CSV files).
"""
