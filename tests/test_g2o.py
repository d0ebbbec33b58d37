"""g2o / TORO interchange: round trips, formats and every kind of bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from cogmap_core.errors import G2oFormatError, InputFileError
from cogmap_core.g2o import format_g2o, read_g2o, write_g2o
from cogmap_core.geometry import compose_scalar, inverse_scalar
from cogmap_core.posegraph import PoseGraph


def small_graph() -> PoseGraph:
    info = np.array([[[10.0, 0.5, 0.1], [0.5, 20.0, 0.2], [0.1, 0.2, 30.0]]] * 2)
    return PoseGraph(
        vertex_ids=np.array([4, 7, 9]),
        poses=np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.3], [2.0, 0.5, -3.0]]),
        edge_from=np.array([0, 1]),
        edge_to=np.array([1, 2]),
        measurements=np.array([[1.0, 0.0, 0.3], [0.9, 0.2, -0.2]]),
        information=info,
        fixed=np.array([True, False, False]),
    )


def test_round_trip_is_exact(tmp_path):
    g = small_graph()
    write_g2o(g, tmp_path / "g.g2o")
    back = read_g2o(tmp_path / "g.g2o")
    np.testing.assert_array_equal(back.vertex_ids, g.vertex_ids)
    np.testing.assert_array_equal(back.poses, g.poses)
    np.testing.assert_array_equal(back.edge_from, g.edge_from)
    np.testing.assert_array_equal(back.edge_to, g.edge_to)
    np.testing.assert_array_equal(back.measurements, g.measurements)
    np.testing.assert_array_equal(back.information, g.information)
    np.testing.assert_array_equal(back.fixed, g.fixed)


def test_reads_benchmark_file(data_dir):
    g = read_g2o(data_dir / "MIT.g2o")
    assert (g.num_vertices, g.num_edges) == (808, 827)
    assert (g.edge_from > g.edge_to).sum() == 20  # SOURCES.md: 20 edges go backwards
    np.testing.assert_allclose(g.information, g.information.transpose(0, 2, 1))


def test_reads_toro_information_order(tmp_path):
    path = tmp_path / "t.graph"
    path.write_text(
        "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\n"
        "EDGE2 0 1 1 0 0 11 12 22 33 13 23\n"  # TORO: xx xy yy tt xt yt
    )
    g = read_g2o(path)
    np.testing.assert_array_equal(g.information[0], [[11, 12, 13], [12, 22, 23], [13, 23, 33]])


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("VERTEX_SE2 0 0 0\n", ":1: VERTEX_SE2 needs 3 values"),
        ("VERTEX_SE2 0 0 0 zero\n", ":1: VERTEX_SE2 has a value that is not a number"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_XYZ 1 0 0 0\n", ":2: unknown tag 'VERTEX_XYZ'"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 5 1 0 0 1 0 0 1 0 1\n", ":2: edge refers to vertex 5"),
        ("VERTEX_SE2 0 nan 0 0\n", ":1: VERTEX_SE2 has a NaN or infinite value"),
        (
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1 0 inf 1 0 0 1 0 1\n",
            ":3: EDGE_SE2 has a NaN",
        ),
        ("", "no VERTEX_SE2/VERTEX2 or EDGE_SE2/EDGE2 line"),
        ("# only a comment\n", "no VERTEX_SE2/VERTEX2 or EDGE_SE2/EDGE2 line"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", ":2: vertex 0 is defined twice"),
        (
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n",
            ":3: information matrix is not positive definite",
        ),
        (
            "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 0 1 0 0 1 0 0 1 0 1\n",
            ":2: EDGE_SE2 links vertex 0 to itself",
        ),
        ("VERTEX_SE2 x 0 0 0\n", ":1: VERTEX_SE2 vertex id 'x' is not an integer"),
    ],
)
def test_bad_input_names_file_and_line(tmp_path, text, fragment):
    path = tmp_path / "bad.g2o"
    path.write_text(text)
    with pytest.raises(G2oFormatError) as info:
        read_g2o(path)
    message = str(info.value)
    assert str(path) in message
    assert fragment in message
    assert "\n" not in message


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_g2o(tmp_path / "missing.g2o")


def test_cli_bad_input_exit_2_and_nothing_written(tmp_path, capsys):
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1\n")
    out = tmp_path / "out.g2o"
    assert main(["optimize", str(bad), str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert f"{bad}:3: EDGE_SE2 has a NaN or infinite value" in err[0]
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [bad]  # no temporary files left either


def test_cli_missing_output_directory(tmp_path, capsys, data_dir):
    out = tmp_path / "no" / "such" / "dir" / "out.g2o"
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("token", [str(2**70), str(-(2**64))])
def test_vertex_id_outside_64_bits_is_a_format_error(tmp_path, capsys, token):
    path = tmp_path / "big.g2o"
    path.write_text(f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 {token} 1 0 0\n")
    with pytest.raises(G2oFormatError) as info:
        read_g2o(path)
    assert str(info.value) == (
        f"{path}:2: VERTEX_SE2 vertex id {token} is out of range (-2^63 to 2^63-1); "
        "renumber the vertices"
    )
    assert main(["optimize", str(path), str(tmp_path / "out.g2o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "out of range" in err


def test_utf8_byte_order_mark_is_ignored(tmp_path):
    path = tmp_path / "bom.g2o"
    path.write_bytes(b"\xef\xbb\xbfVERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nFIX 0\n")
    g = read_g2o(path)
    assert g.vertex_ids.tolist() == [0, 1] and g.fixed.tolist() == [True, False]


def test_edges_only_file_gets_vertices_chained_along_its_edges(tmp_path):
    g = small_graph()
    path = tmp_path / "edges.g2o"
    path.write_text(
        "".join(line for line in format_g2o(g) if line.startswith("EDGE"))
        + "EDGE_SE2 9 12 1 0 0 1 0 0 1 0 1\n"
        + "EDGE_SE2 30 20 2 0 1.5 1 0 0 1 0 1\n"  # a second part, reached backwards from 20
    )
    back = read_g2o(path)
    assert back.vertex_ids.tolist() == [4, 7, 9, 12, 20, 30]
    assert back.num_edges == 4 and not back.fixed.any()
    p7 = compose_scalar((0.0, 0.0, 0.0), g.measurements[0].tolist())
    p9 = compose_scalar(p7, g.measurements[1].tolist())
    p12 = compose_scalar(p9, (1.0, 0.0, 0.0))
    p30 = compose_scalar((0.0, 0.0, 0.0), inverse_scalar((2.0, 0.0, 1.5)))
    expected = [(0.0, 0.0, 0.0), p7, p9, p12, (0.0, 0.0, 0.0), p30]
    np.testing.assert_allclose(back.poses, expected, atol=1e-12)


def test_optimize_an_edges_only_benchmark_file(tmp_path, data_dir, capsys):
    text = (data_dir / "MIT.g2o").read_text().splitlines(keepends=True)
    edges = tmp_path / "mit_edges.g2o"
    edges.write_text("".join(line for line in text if line.startswith("EDGE")))
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(tmp_path / "a.g2o")]) == 0
    full = json.loads(capsys.readouterr().out)
    assert main(["optimize", str(edges), str(tmp_path / "b.g2o")]) == 0
    only = json.loads(capsys.readouterr().out)
    assert (only["vertices"], only["edges"]) == (808, 827)
    assert only["final_cost"] == pytest.approx(full["final_cost"], rel=1e-9)
    assert read_g2o(tmp_path / "b.g2o").num_vertices == 808


def test_ceres_log_lines_stay_off_stderr(tmp_path, capfd):
    path = tmp_path / "huge.g2o"  # the cost overflows: Ceres' evaluation fails
    path.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1e200 0 0 1e200 0 0 1e200 0 1e200\n"
    )
    out = tmp_path / "out.g2o"
    assert main(["optimize", str(path), str(out), "--init", "none"]) == 2
    err = capfd.readouterr().err  # file descriptor 2: glog writes there directly
    assert err == (
        "cogmap optimize: error: Ceres failed: Initial residual and Jacobian evaluation failed.\n"
    )
    assert main(["optimize", str(path), str(out)]) == 2  # LAGO from the huge values overflows
    assert capfd.readouterr().err == (
        "cogmap optimize: error: the LAGO initialisation overflowed: the graph's values are too "
        "large; rescale the graph, or start from its own poses (initialization 'none')\n"
    )
    assert not out.exists()
