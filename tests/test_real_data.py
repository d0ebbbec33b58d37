"""The TUC Lecture Hall log (real odometry and place recognition): the maps beat dead reckoning.

The data lives outside the repository (licence CC BY-NC-SA 4.0): ``../shared/real/tuc`` beside
the repository, or ``$COGMAP_TUC_DIR``. The targets are checked loosely here; the benchmark
``benchmarks/real_data.py`` prints every figure.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from cogmap_core.cognitive_map import MapMode
from cogmap_core.slam import SlamSession
from cogmap_core.sources.detect import detect_format, open_source

TUC = Path(
    os.environ.get("COGMAP_TUC_DIR") or Path(__file__).resolve().parents[2] / "shared/real/tuc"
)
LECTURE_HALL = TUC / "Lecture_Hall_Input.txt"

pytestmark = pytest.mark.skipif(
    not LECTURE_HALL.is_file(),
    reason=f"TUC Lecture Hall data not found at {LECTURE_HALL} (set COGMAP_TUC_DIR)",
)


def test_lecture_hall_maps_beat_dead_reckoning() -> None:
    assert detect_format(LECTURE_HALL) == "tuc"
    reader = open_source(LECTURE_HALL)
    assert reader.info.has_ground_truth and reader.counters.warnings == []
    session = SlamSession(
        reader.map_params, evaluation=reader.evaluation, modes=(MapMode.STANDARD, MapMode.COMPACT)
    )
    session.run(reader.frames())
    log = session.log
    assert log.dead_reckoning_ate() == pytest.approx(12.94, abs=0.05)
    score = session.loop_closure_score()
    assert score is not None and score.total == 110 and score.precision >= 0.85
    standard, compact = session.maps[MapMode.STANDARD], session.maps[MapMode.COMPACT]
    # links weighed by place recognition's precision (measured: 0.371 m and 0.429 m)
    assert session.ate(standard) <= 0.45 and session.ate(compact) <= 0.5
    # measured 1043 / 3124 with the log's odometry scale (0.665) and steps, 941 / 3124 with the
    # model's odometry as it was
    assert compact.num_vertices <= 0.34 * standard.num_vertices
    assert reader.map_params.odometry_scale == pytest.approx(0.6651, abs=1e-4)
    for cmap in (standard, compact):
        fidelity = session.layout_fidelity(cmap, 0.5)
        assert fidelity is not None
        assert min(fidelity.completeness, fidelity.correctness) >= 0.95  # the target
