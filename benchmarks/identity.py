"""Fingerprints of ``cogmap run``'s reports, to show a behaviour-preserving change is one.

Usage::

    python benchmarks/identity.py --save before.json [--lecture-hall PATH] [--only NAME,...]
    # ... change the code ...
    python benchmarks/identity.py --compare before.json

``cogmap run`` (paper parameters for bags, log defaults for logs) runs on the default dataset,
the other three built-in layouts (seed 1, the bags ``benchmarks/map_layouts.py`` caches) and the
Lecture Hall log of the TUC dataset, each into a temporary folder. Recorded per input: the
SHA-256 of every report file, with ``summary.json`` and ``config.json`` fingerprinted without
their timing fields (wall seconds, real-time factor, optimisation seconds), which vary from run
to run. ``--compare`` prints each input's files that differ and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.pipeline import RunOptions, run_headless  # noqa: E402
from benchmarks.map_layouts import bag_for  # noqa: E402
from cogmap_core.datasets.cache import default_dataset_path  # noqa: E402

#: Keys whose values are measured times: left out of the fingerprints.
TIMING_KEYS = frozenset({"wall_s", "realtime_factor", "optimize_wall_s"})
LAYOUTS = ("figure_eight", "long_corridors", "junction_dead_end")
LECTURE_HALL = ROOT.parent / "shared" / "real" / "tuc" / "Lecture_Hall_Input.txt"


def without_timing(value: Any) -> Any:
    """``value`` (parsed JSON) without the :data:`TIMING_KEYS` at any depth."""
    if isinstance(value, dict):
        return {k: without_timing(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [without_timing(v) for v in value]
    return value


def fingerprint(path: Path) -> str:
    """SHA-256 of a report file; JSON files are hashed without their timing fields."""
    data = path.read_bytes()
    if path.suffix == ".json":
        canonical = json.dumps(without_timing(json.loads(data)), sort_keys=True)
        data = canonical.encode()
    return hashlib.sha256(data).hexdigest()


def inputs(lecture_hall: Path) -> dict[str, Path]:
    """The inputs by name: the default dataset, three layouts, Lecture Hall when present."""
    named = {"irat_australia": default_dataset_path()}
    named |= {layout: bag_for(layout, 1) for layout in LAYOUTS}
    if lecture_hall.exists():
        named["lecture_hall"] = lecture_hall
    else:
        print(f"{lecture_hall} is missing: Lecture Hall left out", file=sys.stderr)
    return named


def fingerprints_of(path: Path) -> dict[str, str]:
    """Run ``cogmap run`` on ``path`` into a temporary folder; each file's fingerprint."""
    with tempfile.TemporaryDirectory(prefix="cogmap-identity-") as tmp:
        result = run_headless(path, Path(tmp) / "report", RunOptions())
        return {
            file.name: fingerprint(file)
            for file in sorted(result.out_dir.iterdir())
            if file.is_file()
        }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--save", type=Path, help="write the fingerprints to this JSON file")
    what.add_argument("--compare", type=Path, help="compare with fingerprints saved before")
    parser.add_argument("--lecture-hall", type=Path, default=LECTURE_HALL)
    parser.add_argument("--only", default=None, help="comma-separated input names")
    args = parser.parse_args()
    named = inputs(args.lecture_hall)
    if args.only:
        wanted = set(args.only.split(","))
        named = {k: v for k, v in named.items() if k in wanted}
    saved: dict[str, dict[str, str]] = {}
    if args.compare is not None:
        saved = json.loads(args.compare.read_text())
        named = {k: v for k, v in named.items() if k in saved}
    found: dict[str, dict[str, str]] = {}
    differing = 0
    for name, path in named.items():
        found[name] = fingerprints_of(path)
        if args.compare is None:
            print(f"{name:18} {len(found[name])} files fingerprinted", flush=True)
            continue
        before, now = saved[name], found[name]
        changed = sorted(f for f in before.keys() | now.keys() if before.get(f) != now.get(f))
        differing += bool(changed)
        verdict = "identical" if not changed else "DIFFERENT: " + ", ".join(changed)
        print(f"{name:18} {len(now)} files {verdict}", flush=True)
    if args.save is not None:
        args.save.write_text(json.dumps(found, indent=1, sort_keys=True) + "\n")
        print(f"fingerprints written to {args.save}")
        return 0
    print(f"inputs with a different report: {differing} of {len(found)}")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main())
