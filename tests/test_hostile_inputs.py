"""Hostile and degenerate input files: one line and exit 2 (or a correct report), bounded memory.

Issue 24, items 5-7: the CLI's files (``--params``, a sweep's ``best.json``, session and event
files, camera images in a bag) are checked before anything large is allocated, and inputs that
are valid but degenerate (a map of one vertex) give a report, not a traceback.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets.jpeg import ImageTooLarge, JpegDecoder, image_size
from tests.test_dataset_reader import jpeg, simple_bag, write_bag
from tests.test_faults import one_line_error

ROOT = Path(__file__).resolve().parents[1]


def run_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """``cogmap ARGS`` must fail with exit code 2 and one line; return that line."""
    assert main(list(args)) == 2
    return one_line_error(capsys.readouterr().err)


# ------------------------------------------------------------------------ item 7: --params files
@pytest.fixture(scope="module")
def tiny_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simple_bag(tmp_path_factory.mktemp("bag") / "tiny.bag", n=12)


def test_params_nested_too_deep_is_one_line(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(deep)
    )
    assert line == (
        f"cogmap run: error: {deep}: not a readable JSON file (it is nested too deeply to read)"
    )
    assert not (tmp_path / "r").exists()


def test_params_integer_of_400_digits_is_one_line(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    big = tmp_path / "big.json"
    big.write_text('{"delta": 1' + "0" * 399 + "}")
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(big)
    )
    assert line == (
        f"cogmap run: error: {big}: delta=1" + "0" * 29 + "… (400 characters) is "
        "out of range: neighborhood field threshold (g > delta adds a vertex) must be in (1, 1e+12]"
    )


def test_params_true_is_not_a_number(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    flag = tmp_path / "flag.json"
    flag.write_text('{"alpha": true}')
    line = run_error(capsys, "serve", str(tiny_bag), "--params", str(flag))
    assert line == (
        f"cogmap serve: error: {flag}: alpha=True is not a number: weight of translation in the "
        "neighborhood field (1/m) must be in [0, 1e+06]"
    )


@pytest.mark.parametrize(
    ("entry", "value", "kind"),
    [
        ("", [1, 2], "list"),  # smallest_complete, the default entry
        ("#paper", "fast", "string"),
        ("#front_ate/0", 7, "number"),
    ],
)
def test_best_json_entries_of_the_wrong_type_are_one_line(
    tmp_path: Path, tiny_bag: Path, capsys, entry: str, value: object, kind: str
) -> None:
    best = tmp_path / "best.json"
    content = {"format": "cogmap-sweep-best", "smallest_complete": value, "paper": value}
    content["front_ate"] = [value]
    best.write_text(json.dumps(content))
    name = entry or "#smallest_complete"
    line = run_error(capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params",
                     f"{best}{entry}")  # fmt: skip
    assert line == (
        f"cogmap run: error: {best}{name}: the entry is a {kind}, not a setting (an object of "
        "parameters); the file is not a sweep's best.json as cogmap writes it"
    )
    best.write_text(json.dumps({"format": "cogmap-sweep-best", "front_ate": "none"}))
    line = run_error(capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params",
                     f"{best}#front_ate/0")  # fmt: skip
    assert line == (
        f"cogmap run: error: {best}#front_ate/0: front_ate is a string, not a list of settings; "
        "the file is not a sweep's best.json as cogmap writes it"
    )


def test_a_params_file_larger_than_16_mib_is_not_read(
    tmp_path: Path, tiny_bag: Path, capsys
) -> None:
    huge = tmp_path / "huge.json"
    with huge.open("wb") as handle:
        handle.truncate(17 * 1024 * 1024)  # sparse: nothing is written, nothing may be read
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--params", str(huge)
    )
    assert line == (
        f"cogmap run: error: {huge}: the parameter file has 17825792 bytes, more than the 16 MiB "
        "a parameter file may have"
    )


# ------------------------------------------------------------- item 6: valid input, tiny maps
def test_a_map_of_one_vertex_is_reported(tmp_path: Path, tiny_bag: Path, capsys) -> None:
    """δ = 1000 keeps the compact map at one vertex: no ATE alignment, no correctness."""
    out = tmp_path / "r"
    assert main(["run", str(tiny_bag), "--out", str(out), "--delta", "1000"]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    compact = summary["maps"]["compact"]
    assert compact["vertices"] == 1 and compact["edges"] == 0
    assert compact["correctness"] is None
    assert (out / "map.png").stat().st_size > 0


def tuc_log(folder: Path, lines: int) -> Path:
    """A TUC log of ``lines`` odometry lines (0.1 m/s straight on) with its ground truth."""
    log = folder / "run_Input.txt"
    log.write_text("".join(f"odom2 {0.1 * k:.1f} 0.1 0.0 0.0 0 0 0\n" for k in range(lines)))
    (folder / "run_GT.txt").write_text(
        "".join(f"point2 {0.1 * k:.1f} {0.01 * k:.2f} 0.0 0 0 0 0\n" for k in range(lines))
    )
    return log


@pytest.mark.parametrize("lines", [2, 3])
def test_a_tuc_log_of_a_few_lines_with_ground_truth_is_reported(
    tmp_path: Path, capsys, lines: int
) -> None:
    log = tuc_log(tmp_path, lines)
    out = tmp_path / "r"
    assert main(["run", str(log), "--out", str(out)]) == 0
    assert "Traceback" not in capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == lines
    for entry in summary["maps"].values():
        assert entry["vertices"] == 1 and entry["ate_m"] == 0.0
        assert entry["completeness"] == 1.0 and entry["correctness"] is None
    assert (out / "map.png").stat().st_size > 0


# ------------------------------------------------------- item 5: sizes checked before allocating
MEASURE = r"""
import resource, sys, time
limit = 3 * 1024**3  # virtual memory: a regression fails with MemoryError instead of eating RAM
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from app.cli import main
started = time.perf_counter()
code = main(sys.argv[1:])
seconds = time.perf_counter() - started
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
try:  # this process's own peak: Linux's ru_maxrss keeps the parent's (pytest's) across exec
    with open("/proc/self/status") as status:
        peak = next(int(s.split()[1]) for s in status if s.startswith("VmHWM:")) / 1024
except (OSError, StopIteration, ValueError):
    pass
print(f"MEASURED {code} {seconds:.3f} {peak:.0f}", file=sys.stderr)
"""


@dataclass
class Measured:
    code: int
    out: str
    err: str
    seconds: float
    peak_mb: float


def measured(*args: str, timeout: float = 30.0) -> Measured:
    """``cogmap ARGS`` in a child process: exit code, output, its time and peak memory."""
    proc = subprocess.run(
        [sys.executable, "-c", MEASURE, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )
    *lines, last = proc.stderr.rstrip().splitlines()
    _, code, seconds, peak = last.split()
    return Measured(int(code), proc.stdout, "\n".join(lines), float(seconds), float(peak))


def npy_member(archive: zipfile.ZipFile, name: str, dtype: str, count: int) -> int:
    """Add member ``name``.npy of ``count`` zero elements, streamed; return its size."""
    header = io.BytesIO()
    fields = {"descr": dtype, "fortran_order": False, "shape": (count,)}
    np.lib.format.write_array_header_1_0(header, fields)
    chunk = bytes(64 << 20)
    left = count * np.dtype(dtype).itemsize
    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
        member.write(header.getvalue())
        while left:
            member.write(chunk[: min(left, len(chunk))])
            left -= min(left, len(chunk))
    return len(header.getvalue()) + count * np.dtype(dtype).itemsize


@pytest.fixture(scope="module")
def session_file(tiny_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("session")
    path = folder / "tiny.session.npz"
    assert (
        main(["run", str(tiny_bag), "--out", str(folder / "r"), "--save-session", str(path)]) == 0
    )
    return path


def copy_session(
    source: Path, target: Path, header: str | None = None, drop: tuple[str, ...] = ()
) -> zipfile.ZipFile:
    """A copy of session ``source`` (header text replaced, arrays dropped), open for more."""
    archive = zipfile.ZipFile(target, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1)
    with zipfile.ZipFile(source) as src:
        for item in src.infolist():
            name = item.filename.removesuffix(".npy")
            if name in drop:
                continue
            if name == "header" and header is not None:
                buffer = io.BytesIO()
                np.lib.format.write_array(buffer, np.array(header))
                archive.writestr("header.npy", buffer.getvalue())
            else:
                archive.writestr(item, src.read(item.filename))
    return archive


def session_header(path: Path) -> dict:
    with zipfile.ZipFile(path) as src, src.open("header.npy") as member:
        return json.loads(str(np.lib.format.read_array(member)))


def test_a_session_member_of_1_gib_is_refused_unread(
    session_file: Path, tiny_bag: Path, tmp_path: Path
) -> None:
    """A 5 MB file whose templates inflate to 1 GiB (the issue's: 6 GB in 7.5 MB)."""
    bomb = tmp_path / "bomb.session.npz"
    with copy_session(session_file, bomb, drop=("frontend.templates",)) as archive:
        size = npy_member(archive, "frontend.templates", "|u1", 1 << 30)
    assert bomb.stat().st_size < 8_000_000
    result = measured("run", str(tiny_bag), "--out", str(tmp_path / "r"), "--resume", str(bomb))
    assert result.code == 2 and one_line_error(result.err) == (
        f"cogmap run: error: {bomb}: array frontend.templates holds {size / 1e6:,.1f} MB "
        "uncompressed, more than the 512 MiB a cogmap session file may hold; refused unread"
    )
    assert result.seconds < 10 and result.peak_mb < 400, result
    assert not (tmp_path / "r").exists()


def test_a_session_header_asking_for_a_huge_front_end_is_refused_before_building_it(
    session_file: Path, tiny_bag: Path, tmp_path: Path
) -> None:
    """Pose cells of 1000 x 1000 x 3600 (28.8 GB) in an otherwise intact session."""
    header = session_header(session_file)
    header["frontend"].update(pc_dim_xy=999, pc_dim_th=3599)
    edited = tmp_path / "huge.session.npz"
    copy_session(session_file, edited, json.dumps(header)).close()
    result = measured("run", str(tiny_bag), "--out", str(tmp_path / "r"), "--resume", str(edited))
    assert result.code == 2 and one_line_error(result.err) == (
        f"cogmap run: error: {edited}: the session was made with other front-end settings: "
        "pc_dim_xy=999 (session) vs 11 (this run); resume with the same settings (the "
        "bag's profile and --frontend) or start a new session"
    )
    assert result.seconds < 10 and result.peak_mb < 400, result


def test_a_session_header_nested_200k_deep_is_one_line(
    session_file: Path, tiny_bag: Path, tmp_path: Path, capsys
) -> None:
    deep = tmp_path / "deep.session.npz"
    copy_session(session_file, deep, "[" * 200_000 + "]" * 200_000).close()
    line = run_error(
        capsys, "run", str(tiny_bag), "--out", str(tmp_path / "r"), "--resume", str(deep)
    )
    assert line == (
        f"cogmap run: error: {deep}: the session file's header is not valid JSON; it is corrupt"
    )


def forged_jpeg(width: int, height: int) -> bytes:
    """A small real JPEG whose frame header (SOF0) declares ``width`` x ``height``."""
    data = bytearray(jpeg(0))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


def forged_png(width: int, height: int) -> bytes:
    """A small real PNG whose IHDR declares ``width`` x ``height`` (with a valid CRC)."""
    ok, buffer = cv2.imencode(".png", np.zeros((240, 416), np.uint8))
    assert ok
    data = bytearray(buffer.tobytes())
    data[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")
    data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")
    return bytes(data)


def test_image_sizes_are_read_from_the_headers() -> None:
    assert image_size(jpeg(3)) == (416, 240)
    assert image_size(np.frombuffer(forged_jpeg(65000, 65000), np.uint8)) == (65000, 65000)
    assert image_size(forged_png(30000, 30000)) == (30000, 30000)
    ok, bmp = cv2.imencode(".bmp", np.zeros((8, 8), np.uint8))
    assert image_size(bmp) is None and image_size(b"\xff\xd8\xff\xd9") is None
    decoder = JpegDecoder(cv2.IMREAD_REDUCED_GRAYSCALE_4)
    with pytest.raises(ImageTooLarge, match="image of 65000 x 65000 pixels is larger than the "
                       "16,777,216 pixels decoded"):  # fmt: skip
        decoder.decode(np.frombuffer(forged_jpeg(65000, 65000), np.uint8))
    assert decoder.decode(bmp) == (None, None)  # not handed to OpenCV's other decoders


@pytest.mark.parametrize("forged", ["jpeg", "png"])
def test_frames_declaring_huge_sizes_are_skipped_unread(forged: str, tmp_path: Path) -> None:
    """Two frames of 65000² (JPEG) or 30000² (PNG) among twelve good ones."""
    huge = forged_jpeg(65000, 65000) if forged == "jpeg" else forged_png(30000, 30000)
    frames = [(0.1 + 0.2 * k, huge if k in (4, 7) else jpeg(k)) for k in range(14)]
    odom = [(0.1 * k, 0.1, 0.0) for k in range(30)]
    bag = write_bag(tmp_path / "huge.bag", frames, odom)
    out = tmp_path / "r"
    result = measured("run", str(bag), "--out", str(out))
    assert result.code == 0, result.err
    assert (
        "warning: 2 x camera image larger than 16,777,216 pixels skipped undecoded (first at "
        "t=0.90 s)" in result.out
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 12
    assert summary["read_warnings"]["oversized_images"] == 2
    assert "undecodable_images" not in summary["read_warnings"]
    assert result.seconds < 10 and result.peak_mb < 400, result


def test_a_bag_of_huge_frames_only_is_one_line(tmp_path: Path, capsys) -> None:
    frames = [(0.1 + 0.2 * k, forged_jpeg(65000, 65000)) for k in range(5)]
    bag = write_bag(tmp_path / "huge.bag", frames, [(0.1 * k, 0.1, 0.0) for k in range(12)])
    line = run_error(capsys, "run", str(bag), "--out", str(tmp_path / "r"))
    assert line == (
        f"cogmap run: error: all 5 camera images in {bag} are larger than the 16,777,216 pixels "
        "cogmap decodes (the first declares 65000 x 65000); check the camera topic"
    )
