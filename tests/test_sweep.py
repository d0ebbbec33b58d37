"""Parameter sweeps: spec parsing, one cell's figures, Pareto fronts, the results table, the
Dask engine (interrupted part-way and resumed), the ``cogmap sweep`` command and ``--params``."""

from __future__ import annotations

import csv
import errno
import json
import math
from pathlib import Path

import numpy as np
import pytest

from app.cli import build_parser, main
from app.cli_common import map_changes_from_args
from app.params_file import load_params_changes
from app.sweep import (
    RESULT_COLUMNS,
    BagEvents,
    ResultsTable,
    Sweep,
    SweepError,
    SweepOptions,
    bag_source,
    prepare_events,
    run_serially,
)
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets import BagTopics, MazeConfig, generate_maze_bag
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.sweep import (
    FIGURE_COLUMNS,
    SettingFigures,
    SweepSpec,
    beats,
    evaluate_cell,
    front_ate,
    front_completeness,
    parameter_name,
    pareto_mask,
    parse_parameter,
    smallest_complete,
    sweep_spec,
)
from tests.test_faults import one_line_error

DATA = Path(__file__).parent / "data"
RECORDED = DATA / "figure_eight_3laps.events.npz"


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch):
    """Event files cached by a sweep go to a temporary cache, not the user's."""
    monkeypatch.setenv("COGMAP_CACHE", str(tmp_path_factory.mktemp("cache")))


@pytest.fixture(scope="module")
def tiny_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two laps of the figure eight at 6 frames/s: 802 frames, made in about 2 s."""
    out = tmp_path_factory.mktemp("sweep_bags") / "eight.bag"
    generate_maze_bag(out, MazeConfig(layout="figure_eight", laps=2, seed=3, fps=6), workers=2)
    return out


@pytest.fixture(scope="module")
def recorded_log() -> EventLog:
    return EventLog.from_recording(load_event_file(RECORDED))


# --------------------------------------------------------------------------- specs
def test_a_range_is_numpy_linspace_inclusive():
    spec = parse_parameter("delta", "2:8:13", random=False)
    assert spec.values == tuple(float(v) for v in np.linspace(2, 8, 13))
    assert spec.values[:3] == (2.0, 2.5, 3.0) and spec.values[-1] == 8.0
    assert parse_parameter("alpha", "1:100:3:log", random=False).values == tuple(
        float(v) for v in np.geomspace(1, 100, 3)
    )
    assert parse_parameter("t-interval", "1, 2,4", random=False).values == (1.0, 2.0, 4.0)
    assert parse_parameter("T_TOTAL", "50", random=False).values == (50.0,)
    assert parse_parameter("beta", [5, 10.5], random=False).values == (5.0, 10.5)


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("gamma", "1:2:3", "unknown map parameter 'gamma'; known: alpha, beta, delta"),
        ("delta", "8:2:13", "delta '8:2:13': inverted range (8 > 2); write LOW:HIGH:COUNT"),
        ("delta", "2:8:0", "delta '2:8:0': empty range (0 values)"),
        ("delta", "2:8:1", "delta '2:8:1': empty range (1 values)"),
        ("delta", "3:3:5", "delta '3:3:5': empty range (both ends are 3)"),
        ("delta", "2:8", "delta '2:8': a grid needs the number of values"),
        ("delta", "2:8:x", "COUNT 'x' is not a whole number"),
        ("delta", "2,two", "delta '2,two': 'two' is not a number"),
        ("delta", "2,3,2", "a value is repeated"),
        ("delta", "0.5:4:3", "delta=0.5 is out of range"),
        ("alpha", "0:1:3:log", "a log range needs LOW > 0"),
        ("delta", "", "delta: no values given"),
    ],
)
def test_bad_values_name_the_problem(name, text, message):
    with pytest.raises(ParameterError) as info:
        parse_parameter(name, text, random=False)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_a_grid_is_every_combination_in_parameter_order():
    spec = sweep_spec({"t-interval": "1,2", "delta": "2:8:3", "huber_scale": "0.2"})
    assert spec.swept == ("delta", "t_interval")
    assert [(p.delta, p.t_interval) for p in spec.settings()] == [
        (2.0, 1.0),
        (2.0, 2.0),
        (5.0, 1.0),
        (5.0, 2.0),
        (8.0, 1.0),
        (8.0, 2.0),
    ]
    assert {p.huber_scale for p in spec.settings()} == {0.2}
    # the paper's setting keeps the sweep's fixed values of the other parameters
    assert spec.paper_params() == MapParams(huber_scale=0.2)


def test_a_sweep_needs_something_to_sweep():
    with pytest.raises(ParameterError, match="nothing to sweep"):
        sweep_spec({"delta": "3"})
    with pytest.raises(ParameterError, match="nothing to sweep"):
        sweep_spec({})
    with pytest.raises(ParameterError, match="more than 100000"):
        sweep_spec({"delta": "2:8:1000", "alpha": "1:20:1000"})
    with pytest.raises(ParameterError, match="samples 0"):
        sweep_spec({"delta": "2:8"}, samples=0)


def test_random_search_is_seeded_and_stays_in_range():
    values = {"delta": "2:8", "alpha": "1:100:log", "beta": "5,10", "t_interval": "1:3:3"}
    first = sweep_spec(values, samples=40, seed=7).settings()
    assert first == sweep_spec(values, samples=40, seed=7).settings()
    assert first != sweep_spec(values, samples=40, seed=8).settings()
    assert len(first) == 40
    assert all(2.0 <= p.delta <= 8.0 for p in first)
    assert all(1.0 <= p.alpha <= 100.0 for p in first)
    assert {p.beta for p in first} == {5.0, 10.0}
    assert {p.t_interval for p in first} == {1.0, 2.0, 3.0}
    # log-uniform: about half of the draws below the geometric middle (10)
    assert 10 <= sum(p.alpha < 10 for p in first) <= 30


def test_spec_files_toml_and_yaml(tmp_path: Path):
    from app.cmd_sweep import read_spec_file, spec_from_args

    def spec_file(path: Path) -> SweepSpec:  # what `cogmap sweep --spec PATH` sweeps
        args = build_parser().parse_args(["sweep", "--out", str(tmp_path), "--spec", str(path)])
        return spec_from_args(args)

    toml = tmp_path / "grid.toml"
    toml.write_text('delta = "2:8:4"\nt_interval = [1, 2]\n')
    spec = spec_file(toml)
    assert len(spec.settings()) == 8 and spec.samples is None
    yaml_file = tmp_path / "random.yaml"
    yaml_file.write_text("samples: 5\nseed: 3\nparameters:\n  delta: '2:8'\n  beta: [5, 10]\n")
    spec = spec_file(yaml_file)
    assert spec.samples == 5 and spec.seed == 3 and len(spec.settings()) == 5
    bad = tmp_path / "bad.toml"
    bad.write_text('gamma = "1:2:3"\n')
    with pytest.raises(ParameterError, match=r"bad.toml: unknown map parameter 'gamma'"):
        spec_file(bad)
    broken = tmp_path / "broken.toml"
    broken.write_text("delta = [1,\n")
    with pytest.raises(InputFileError, match="broken.toml: not a readable spec file"):
        read_spec_file(broken)


# --------------------------------------------------------------------------- one cell
def test_a_cell_is_the_map_built_from_the_events(recorded_log: EventLog):
    params = MapParams(delta=5.0, t_interval=1.0)
    figures = evaluate_cell(recorded_log, params)
    cmap = CognitiveMap(MapMode.COMPACT, params)
    cmap.apply_all(recorded_log.events)
    end = recorded_log.frame_time[-1]
    cmap.finish(end)
    fidelity = recorded_log.layout_fidelity(cmap)
    middle = end - 0.5 * (end - recorded_log.frame_time[0])
    growth = recorded_log.size_change(cmap, middle, end)
    assert figures["vertices"] == cmap.num_vertices
    assert figures["edges"] == cmap.num_edges
    assert figures["loop_edges"] == cmap.num_loop_edges
    assert figures["clusters"] == len(cmap.clusters)
    assert figures["optimizations"] == len(cmap.optimizations)
    assert figures["ate_m"] == recorded_log.map_ate(cmap)
    assert figures["completeness"] == fidelity.completeness
    assert figures["correctness"] == fidelity.correctness
    assert figures["size_change"] == growth.change_without_exploration
    assert figures["size_change_raw"] == growth.change
    assert figures["exploration_vertices"] == growth.exploration_vertices
    # a larger threshold keeps fewer vertices; the standard map keeps every proposal
    assert evaluate_cell(recorded_log, MapParams(delta=8.0))["vertices"] < figures["vertices"]
    standard = evaluate_cell(recorded_log, params, MapMode.STANDARD)
    proposals = sum(type(e).__name__ == "CreateVertex" for e in recorded_log.events)
    assert standard["vertices"] == proposals


# --------------------------------------------------------------------------- fronts
def _setting(vertices: float, ate: float, completeness: float, delta: float) -> SettingFigures:
    return SettingFigures(MapParams(delta=delta), vertices, vertices, ate, completeness, 1.0, 0, 1)


def test_pareto_front_and_the_smallest_complete_map():
    costs = np.array([[1, 5], [2, 3], [2, 4], [3, 3], [4, 1], [4, 1], [5, np.nan]], float)
    assert pareto_mask(costs).tolist() == [True, True, False, False, True, True, False]
    a = _setting(100, 0.02, 0.999, 2.0)
    b = _setting(80, 0.03, 0.990, 3.0)
    c = _setting(60, 0.05, 0.950, 4.0)
    d = _setting(80, 0.04, 0.995, 5.0)
    e = _setting(90, 0.02, 0.999, 6.0)
    settings = [a, b, c, d, e]
    assert front_ate(settings) == [c, b, e]
    assert front_completeness(settings) == [c, d, e]
    assert smallest_complete(settings) == b
    assert smallest_complete(settings, 0.999) == e
    assert smallest_complete(settings, 1.0) is None
    assert beats(e, a) and not beats(b, a) and not beats(a, a)


# --------------------------------------------------------------------------- results table
def test_results_table_round_trips_and_survives_a_cut_line(tmp_path: Path):
    path = tmp_path / "results.csv"
    table = ResultsTable(path)
    row = {c: None for c in RESULT_COLUMNS}
    row.update(MapParams(delta=4 / 3).to_dict())
    row.update(key="k1", run=1, bag="b", bag_key="bk", map="compact", status="ok", error="")
    row.update(vertices=12, ate_m=0.1 + 0.2, completeness=1.0, size_change=float("nan"))
    table.append(row)
    row2 = dict(row, key="k2", status="error", error='ValueError: bad, "quoted"', vertices=None)
    table.append(row2)
    with path.open("a") as handle:
        handle.write("k3,1,b,bk,comp")  # a kill in the middle of a line
    again = ResultsTable(path)
    assert [r["key"] for r in again.rows] == ["k1", "k2"]
    first = again.rows[0]
    assert first["delta"] == 4 / 3 and first["ate_m"] == 0.1 + 0.2 and first["vertices"] == 12
    assert math.isnan(first["size_change"]) and first["correctness"] is None
    assert again.rows[1]["error"] == 'ValueError: bad, "quoted"'
    assert path.read_text().endswith("\n")
    again.append(dict(row, key="k3"))
    assert [r["key"] for r in ResultsTable(path).rows] == ["k1", "k2", "k3"]
    assert ResultsTable(path).latest()["k3"]["vertices"] == 12
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(SweepError, match="its columns are not this cogmap's sweep table"):
        ResultsTable(other)


def test_figures_are_written_atomically(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    # pareto.png (and cogmap run's figures) go through app.report_figures.save_figure: the PNG
    # and the SVG beside it, each written atomically
    import os

    from app.report_figures import save_figure, size_figure

    def figure() -> object:
        return size_figure({}, 10.0)

    target = tmp_path / "pareto.png"
    assert save_figure(figure(), target) == [target, tmp_path / "pareto.svg"]
    assert target.read_bytes()[:4] == b"\x89PNG"
    assert b"<svg" in (tmp_path / "pareto.svg").read_bytes()[:400]
    target.write_bytes(b"the previous figure")
    (tmp_path / "pareto.svg").write_bytes(b"the previous svg")

    def full_disk(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left on device"):
        save_figure(figure(), target)
    assert target.read_bytes() == b"the previous figure"
    assert (tmp_path / "pareto.svg").read_bytes() == b"the previous svg"


# --------------------------------------------------------------------------- the engine
GRID = {"delta": "2,3.746,6,8", "t_interval": "0.5,2"}  # 8 settings, the paper's among them


@pytest.fixture(scope="module")
def in_process_client():
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0"
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        yield client


def _read_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_interrupted_sweep_resumes_without_recomputing(
    tiny_bag: Path, tmp_path: Path, in_process_client
):
    out = tmp_path / "sweep"
    source = bag_source(tiny_bag, frontend_config_for(tiny_bag), BagTopics())
    options = SweepOptions(spec=sweep_spec(GRID))
    seen: list[int] = []

    def stop_part_way(done: int, failed: int) -> None:
        seen.append(done)
        if done == 2:
            raise KeyboardInterrupt  # Ctrl-C after the second finished cell

    first = Sweep([source], out, options, on_result=stop_part_way, client=in_process_client)
    assert len(first.cells) == 8
    with pytest.raises(KeyboardInterrupt):
        first.run()
    manifest = json.loads((out / "sweep.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["cells"] == 8
    assert not (out / "best.json").exists() and not (out / "pareto.png").exists()
    run1 = _read_rows(out / "results.csv")
    assert 2 <= len(run1) < 8  # cells finished meanwhile are kept too
    assert {r["run"] for r in run1} == {"1"} and {r["status"] for r in run1} == {"ok"}

    second = Sweep([source], out, options, client=in_process_client)
    result = second.run()
    assert (result.cells, result.skipped, result.computed) == (8, len(run1), 8 - len(run1))
    rows = _read_rows(out / "results.csv")
    assert rows[: len(run1)] == run1  # untouched
    run2 = rows[len(run1) :]
    assert {r["run"] for r in run2} == {"2"}
    keys = [r["key"] for r in rows]
    assert len(keys) == len(set(keys)) == 8  # nothing computed twice
    assert sorted(keys) == sorted(c.key for c in second.cells)
    assert json.loads((out / "sweep.json").read_text())["status"] == "complete"
    assert (out / "pareto.png").stat().st_size > 0 and (out / "pareto.svg").stat().st_size > 0

    # the same figures as the cells built one by one in this process
    events = {source.key: prepare_events(source, out)}
    serial: dict[str, dict] = {}
    run_serially(second.cells, events, lambda cell, outcome: serial.update({cell.key: outcome}))
    table = ResultsTable(out / "results.csv").latest()
    assert len(serial) == 8 and set(serial) == set(table)
    for key, outcome in serial.items():
        assert {c: table[key][c] for c in FIGURE_COLUMNS} == {c: outcome[c] for c in FIGURE_COLUMNS}

    best = json.loads((out / "best.json").read_text())
    assert best["complete"] is True and best["cells"] == {"total": 8, "failed": 0}
    assert best["paper_in_grid"] is True and best["settings"] == 8
    assert best["paper"]["params"] == MapParams().to_dict()
    by_params = {
        json.dumps(MapParams(**{k: r[k] for k in MapParams().to_dict()}).to_dict()): r
        for r in table.values()
    }
    smallest = min(
        (r for r in table.values() if r["completeness"] >= 0.98),
        key=lambda r: (r["vertices"], r["ate_m"], -r["completeness"]),
    )
    assert best["smallest_complete"]["params"]["delta"] == smallest["delta"]
    assert best["smallest_complete"]["vertices"] == smallest["vertices"]
    assert best["front_ate"]
    for entry in best["front_ate"]:
        row = by_params[json.dumps(entry["params"])]
        assert not any(
            r["vertices"] <= row["vertices"]
            and r["ate_m"] <= row["ate_m"]
            and (r["vertices"] < row["vertices"] or r["ate_m"] < row["ate_m"])
            for r in table.values()
        )

    # a third run finds everything done and needs no cluster at all
    unreachable = SweepOptions(
        spec=sweep_spec(GRID), scheduler="tcp://127.0.0.1:9", connect_timeout=0.5
    )
    third = Sweep([source], out, unreachable).run()
    assert (third.computed, third.skipped) == (0, 8)
    assert len(_read_rows(out / "results.csv")) == 8


def test_a_failing_cell_is_recorded_and_the_sweep_goes_on(tmp_path: Path, in_process_client):
    # an event file whose links point at vertices that were never created: every map fails
    from cogmap_core.event_file import EventRecording, save_event_file
    from cogmap_core.events import CreateVertex, LinkToVertex, Odometry

    bad = tmp_path / "broken.events.npz"
    events = [CreateVertex(0.0, 0, 0), Odometry(0.1, 0.1, 0.0), LinkToVertex(0.2, 7, 0.0)]
    save_event_file(
        bad,
        EventRecording(events, np.array([1, 2, 3]), np.array([0.0, 0.1, 0.2]), np.zeros((3, 3))),
    )
    good = RECORDED
    sources = [bag_source(p, None, BagTopics()) for p in (good, bad)]
    out = tmp_path / "sweep"
    sweep = Sweep(
        sources, out, SweepOptions(spec=sweep_spec({"delta": "3,6"})), client=in_process_client
    )
    with pytest.raises(SweepError, match=r"3 of 6 cells failed \(first: EventError"):
        sweep.run()
    rows = _read_rows(out / "results.csv")
    assert len(rows) == 6
    assert {r["status"] for r in rows if r["bag"] == good.name} == {"ok"}
    assert {r["status"] for r in rows if r["bag"] == bad.name} == {"error"}
    best = json.loads((out / "best.json").read_text())
    assert best["complete"] is False and best["cells"]["failed"] == 3
    assert best["front_ate"] == []  # no setting was built on every bag
    assert json.loads((out / "sweep.json").read_text())["status"] == "incomplete"


def test_a_finished_sweep_resumes_without_loading_the_events(
    tmp_path: Path, in_process_client, monkeypatch: pytest.MonkeyPatch
):
    import app.sweep.cells
    import app.sweep.events

    source = bag_source(RECORDED, None, BagTopics())
    options = SweepOptions(spec=sweep_spec({"delta": "3,6"}))
    out = tmp_path / "sweep"
    assert Sweep([source], out, options, client=in_process_client).run().computed == 3
    results, best = (out / "results.csv").read_bytes(), (out / "best.json").read_bytes()
    (record,) = json.loads((out / "sweep.json").read_text())["bags"]
    expected_ate = EventLog.from_recording(load_event_file(RECORDED)).dead_reckoning_ate()
    assert record["dead_reckoning_ate_m"] == expected_ate

    def refuse(path: Path) -> None:
        raise AssertionError(f"a finished sweep loaded {path}")

    monkeypatch.setattr(app.sweep.events, "load_event_file", refuse)
    monkeypatch.setattr(app.sweep.cells, "load_event_file", refuse)
    said: list[str] = []
    again = Sweep([source], out, options, say=said.append).run()  # no cluster needed either
    assert (again.computed, again.skipped, again.failed) == (0, 3, 0)
    assert (out / "results.csv").read_bytes() == results
    assert (out / "best.json").read_bytes() == best
    manifest = json.loads((out / "sweep.json").read_text())
    assert manifest["status"] == "complete" and manifest["bags"] == [record]
    assert any("every cell done, events not loaded" in line for line in said)

    # a manifest without the figure (older, or cut short): the events are loaded, it is computed
    manifest["bags"] = [{k: v for k, v in record.items() if k != "dead_reckoning_ate_m"}]
    (out / "sweep.json").write_text(json.dumps(manifest))
    loaded: list[Path] = []

    def counting(path: Path) -> object:
        loaded.append(Path(path))
        return load_event_file(path)

    monkeypatch.setattr(app.sweep.events, "load_event_file", counting)
    monkeypatch.setattr(app.sweep.cells, "load_event_file", counting)
    assert Sweep([source], out, options).run().computed == 0
    assert loaded == [out / "events" / source.events_name]
    assert json.loads((out / "sweep.json").read_text())["bags"] == [record]
    assert (out / "results.csv").read_bytes() == results
    assert (out / "best.json").read_bytes() == best


def test_workers_can_read_the_events_from_the_folder(tmp_path: Path, in_process_client):
    from app.sweep import check_worker_paths

    source = bag_source(RECORDED, None, BagTopics())
    options = SweepOptions(spec=sweep_spec({"delta": "3,6"}), ship_events=False)
    result = Sweep([source], tmp_path / "sweep", options, client=in_process_client).run()
    assert (result.computed, result.failed) == (3, 0)
    missing = tmp_path / "elsewhere" / "x.events.npz"
    with pytest.raises(SweepError) as info:
        check_worker_paths(in_process_client, [str(missing)])
    assert str(info.value).endswith(
        f"cannot read {missing}; put the sweep folder on a path every worker shares, or ship "
        "the events (--worker-events ship)"
    )


# --------------------------------------------------------------------------- the command
def _error_line(capsys: pytest.CaptureFixture[str]) -> str:
    """The command's only error line (progress lines may come before it)."""
    return one_line_error(capsys.readouterr().err)


def test_cogmap_sweep_end_to_end(tiny_bag: Path, tmp_path: Path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", str(tiny_bag), "--out", str(out), "--delta", "2,8", "--t-interval", "0.5,2"]
    assert main(args + ["--workers", "2"]) == 0
    captured = capsys.readouterr()
    assert "running the front end once" in captured.err
    assert "local Dask cluster, 2 worker processes x 1 thread" in captured.err
    assert "5 cells: 5 computed now, 0 from earlier runs" in captured.out
    rows = _read_rows(out / "results.csv")
    assert len(rows) == 5 and {r["status"] for r in rows} == {"ok"}
    assert {(float(r["delta"]), float(r["t_interval"])) for r in rows} == {
        (2.0, 0.5),
        (2.0, 2.0),
        (8.0, 0.5),
        (8.0, 2.0),
        (3.746, 2.0),
    }
    assert all(r["worker"] for r in rows)
    (events_file,) = (out / "events").iterdir()
    assert load_event_file(events_file).frames == 802
    manifest = json.loads((out / "sweep.json").read_text())
    assert manifest["status"] == "complete" and manifest["swept"] == ["delta", "t_interval"]
    assert (out / "pareto.png").read_bytes()[:4] == b"\x89PNG"

    # the same command again: nothing to compute, no front end
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "5 cells: 0 computed now, 5 from earlier runs" in captured.out
    assert "running the front end" not in captured.err

    # another sweep of the same bag elsewhere: its events come from the cache
    other = tmp_path / "other"
    assert main(["sweep", str(tiny_bag), "--out", str(other), "--delta", "4,5"]) == 0
    captured = capsys.readouterr()
    assert "events from the cache" in captured.err
    assert "running the front end" not in captured.err

    # --params best.json: the smallest complete map; other entries by name
    best = json.loads((out / "best.json").read_text())
    parsed = build_parser().parse_args(["serve", "--params", str(out / "best.json")])
    assert MapParams().with_changes(**map_changes_from_args(parsed)) == MapParams(
        **best["smallest_complete"]["params"]
    )
    parsed = build_parser().parse_args(
        ["serve", "--params", f"{out / 'best.json'}#front_ate/0", "--t-total", "50"]
    )
    expected = MapParams(**best["front_ate"][0]["params"]).with_changes(t_total=50.0)
    assert MapParams().with_changes(**map_changes_from_args(parsed)) == expected
    assert (
        MapParams().with_changes(**load_params_changes(f"{out / 'best.json'}#paper")) == MapParams()
    )

    # a different sweep into the same folder is refused
    assert main(["sweep", str(tiny_bag), "--out", str(out), "--delta", "2,9"]) == 2
    assert _error_line(capsys) == (
        f"cogmap sweep: error: {out} holds another sweep (other settings, bags, map or bag "
        "contents); choose another --out, or re-run that sweep's own command"
    )


def test_params_files(tmp_path: Path, capsys):
    flat = tmp_path / "flat.json"
    flat.write_text('{"delta": 5.5, "integration_radius": 0.2}')
    assert MapParams().with_changes(**load_params_changes(str(flat))) == MapParams(
        delta=5.5, integration_radius=0.2
    )
    bad = tmp_path / "bad.json"
    bad.write_text('{"gamma": 1}')
    with pytest.raises(InputFileError, match=r"bad.json: unknown map parameter\(s\) \['gamma'\]"):
        load_params_changes(str(bad))
    out_of_range = tmp_path / "range.json"
    out_of_range.write_text('{"delta": 0.5}')
    assert main(["serve", "--params", str(out_of_range)]) == 2
    assert _error_line(capsys).startswith("cogmap serve: error: ")
    best = tmp_path / "best.json"
    best.write_text(json.dumps({"format": "cogmap-sweep-best", "smallest_complete": None}))
    with pytest.raises(InputFileError, match="the sweep has no smallest_complete setting"):
        load_params_changes(str(best))
    with pytest.raises(InputFileError, match=r"front_ate has 0 settings"):
        load_params_changes(f"{best}#front_ate/0")
    assert main(["run", "--out", str(tmp_path / "r"), "--params", str(tmp_path / "no.json")]) == 2
    assert _error_line(capsys) == (
        f"cogmap run: error: {tmp_path / 'no.json'}: no such parameter file; give a JSON file, "
        "e.g. best.json"
    )


def test_param_names_are_spelled_alike_in_sweeps_and_maps(tmp_path: Path):
    from app.cmd_sweep import spec_from_args

    # one spelling rule: spaces dropped, dashes as underscores, any case
    assert parameter_name(" Integration-Radius ") == "integration_radius"
    spellings = ["Integration-Radius=0.2", " huber-scale =0.3", "GATE_HEADING=0.5"]
    args = build_parser().parse_args(["serve"] + [f"--param={p}" for p in spellings])
    assert map_changes_from_args(args) == {
        "integration_radius": 0.2,
        "huber_scale": 0.3,
        "gate_heading": 0.5,
    }
    sweep_args = ["sweep", "--out", str(tmp_path)] + [f"--param={p},0.1" for p in spellings]
    spec = spec_from_args(build_parser().parse_args(sweep_args))
    assert spec.swept == ("huber_scale", "integration_radius", "gate_heading")
    # the messages each command had: run/serve name every unknown name, sweep the known ones
    args = build_parser().parse_args(["serve", "--param", "Gamma=1", "--param", "DELTA=4"])
    with pytest.raises(ParameterError, match="use --delta instead"):
        map_changes_from_args(args)
    args = build_parser().parse_args(["serve", "--param", "Gamma=1"])
    with pytest.raises(ParameterError, match=r"unknown map parameter\(s\) \['gamma'\]"):
        map_changes_from_args(args)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--param", "gamma=1:2:3"], "unknown map parameter 'gamma'; known: alpha, beta"),
        (["--delta", "8:2:5"], "delta '8:2:5': inverted range (8 > 2); write LOW:HIGH:COUNT"),
        (["--delta", "2:8:0"], "delta '2:8:0': empty range (0 values)"),
        (["--delta", "2,3", "--param", "delta=4,5"], "delta is given twice"),
        (["--delta", "2:8:3", "--samples", "0"], "samples 0: give a whole number >= 1"),
        (["--delta", "2,3", "--workers", "0"], "--workers 0: give at least 1"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(extra, message, tmp_path: Path, capsys):
    out = tmp_path / "sweep"
    assert main(["sweep", str(RECORDED), "--out", str(out)] + extra) == 2
    line = _error_line(capsys)
    assert line.startswith("cogmap sweep: error: ") and message in line
    assert not out.exists()  # rejected before anything is written


def test_sweep_does_not_offer_no_ground_truth(tmp_path: Path, capsys):
    # a sweep measures every map against the ground truth: its parser has no such option, so
    # argparse rejects it as unrecognized (run and serve keep it)
    with pytest.raises(SystemExit) as info:
        main(["sweep", "--help"])
    assert info.value.code == 0
    sweep_help = capsys.readouterr().out
    assert "--gt-topic" in sweep_help and "--no-ground-truth" not in sweep_help
    for command in (["run", "--out", str(tmp_path / "run")], ["serve"]):
        assert build_parser().parse_args([*command, "--no-ground-truth"]).no_ground_truth
    out = tmp_path / "sweep"
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(RECORDED), "--out", str(out), "--delta", "2,3", "--no-ground-truth"])
    assert info.value.code == 2
    assert _error_line(capsys) == (
        "cogmap sweep: error: unrecognized arguments: --no-ground-truth; see cogmap sweep --help"
    )
    assert not out.exists()


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("missing.toml", None, "missing.toml: no such spec file"),
        ("spec.txt", "delta = 1", "spec.txt: spec files are .toml, .yaml, .yml or .json"),
        ("spec.json", "[1]", 'spec.json: expected a table of parameters, e.g. delta = "2:8:13"'),
        (
            "spec.toml",
            "parameters = 3",
            "spec.toml: 'parameters' must be a table of parameter = values",
        ),
        ("spec.toml", "delta = [", "spec.toml: not a readable spec file ("),
    ],
)
def test_a_bad_spec_file_is_one_line_and_exit_2(name, content, message, tmp_path: Path, capsys):
    spec = tmp_path / name
    if content is not None:
        spec.write_text(content)
    out = tmp_path / "sweep"
    assert main(["sweep", str(RECORDED), "--out", str(out), "--spec", str(spec)]) == 2
    line = _error_line(capsys)
    # (a TOML error is followed by the parser's own words)
    assert line.startswith(f"cogmap sweep: error: {tmp_path / message}"), line
    assert not out.exists()


def test_unreachable_scheduler_and_bad_bags(tmp_path: Path, capsys):
    out = tmp_path / "sweep"
    code = main(
        [
            "sweep",
            str(RECORDED),
            "--out",
            str(out),
            "--delta",
            "2,3",
            "--scheduler",
            "tcp://127.0.0.1:9",
            "--connect-timeout",
            "0.5",
        ]
    )
    assert code == 2
    assert _error_line(capsys).startswith(
        "cogmap sweep: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9 ("
    )
    assert json.loads((out / "sweep.json").read_text())["status"] == "failed"
    assert not (out / "best.json").exists()

    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(b"#ROSBAG V2.0\n" + bytes(200))
    out2 = tmp_path / "sweep2"
    assert main(["sweep", str(garbage), "--out", str(out2), "--delta", "2,3"]) == 2
    line = _error_line(capsys)
    assert line == (
        f"cogmap sweep: error: {garbage} has a damaged bag header; it is corrupt, copy it again"
    )
    assert json.loads((out2 / "sweep.json").read_text())["status"] == "failed"
    assert _read_rows(out2 / "results.csv") == []  # no cell was run

    assert main(["sweep", str(tmp_path / "none.bag"), "--out", str(out2), "--delta", "2,3"]) == 2
    assert "none.bag: no such bag" in _error_line(capsys)

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main(["sweep", str(RECORDED), "--out", str(foreign), "--delta", "2,3"]) == 2
    assert _error_line(capsys) == (
        f"cogmap sweep: error: {foreign} is not empty and holds no sweep; choose another --out"
    )
    assert (foreign / "notes.txt").read_text() == "mine"


def test_bag_events_reports_dead_reckoning(tmp_path: Path):
    source = bag_source(RECORDED, None, BagTopics())
    events = prepare_events(source, tmp_path)
    assert isinstance(events, BagEvents)
    log = EventLog.from_recording(load_event_file(RECORDED))
    assert events.dead_reckoning_ate_m == log.dead_reckoning_ate()
    assert events.frames == log.frames and events.origin == "event file"
    assert events.events_path.read_bytes() == RECORDED.read_bytes()
