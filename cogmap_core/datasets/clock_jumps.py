"""Jumps back of a ROS1 bag's record clock, and the messages they make the reader drop.

Planned on the bag's index when :class:`~cogmap_core.datasets.rosbag_reader.BagReader` opens it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rosbags.interfaces import Connection

#: A topic's record time going back by more than this (s) in write order is a clock jump.
CLOCK_JUMP_TOLERANCE = 0.5
CLOCK_JUMP_POLICIES = ("drop", "stop")


@dataclass(frozen=True)
class ClockJump:
    """A jump back of the record clock.

    Attributes:
        time: data time (s) the clock had reached when it jumped.
        back: how far it went back (s).
        dropped: messages dropped because of it (the overlap, or everything after for "stop").

    """

    time: float
    back: float
    dropped: int


def plan_clock_jumps(
    connections: list[Connection], policy: str, t0_ns: int
) -> list[ClockJump] | None:
    """Drop the messages of ROS1 ``connections`` caught in record-clock jumps; None if none.

    The bag's index lists each message's record time and position; in position (write) order a
    topic's record time never goes back unless the recorder's clock did. After a jump of more
    than :data:`CLOCK_JUMP_TOLERANCE`, policy ``"drop"`` removes that topic's messages until its
    record time passes the time reached before the jump; ``"stop"`` removes everything after the
    first jump. The removal is done on the reader's index, so dropped messages are never read.
    Bags without such an index (ROS2) are left alone.
    """
    tol_ns = int(CLOCK_JUMP_TOLERANCE * 1e9)
    per_topic: list[tuple[Connection, list[Any], list[Any]]] = []
    jumps: list[tuple[int, int, int]] = []  # (high-water ns, back ns, dropped)
    for conn in connections:
        indexes = getattr(getattr(conn, "owner", None), "indexes", None)
        entries = indexes.get(conn.id) if isinstance(indexes, dict) else None
        if not isinstance(entries, list) or not all(
            hasattr(e, "chunk_pos") and hasattr(e, "offset") for e in entries[:1]
        ):
            return None
        in_write_order = sorted(entries, key=lambda e: (e.chunk_pos, e.offset))
        kept: list[Any] = []
        high: int | None = None
        resume: int | None = None
        stopped = False
        for entry in in_write_order:
            t = int(entry.time)
            if stopped or (resume is not None and t < resume):
                jumps[-1] = (jumps[-1][0], jumps[-1][1], jumps[-1][2] + 1)
                continue
            resume = None
            if high is not None and t < high - tol_ns:
                jumps.append((high, high - t, 1))
                stopped = policy == "stop"
                resume = high
                continue
            high = t if high is None else max(high, t)
            kept.append(entry)
        if len(kept) != len(entries):
            per_topic.append((conn, indexes, sorted(kept, key=lambda e: int(e.time))))
    if not jumps:
        return None
    for conn, indexes, kept in per_topic:
        indexes[conn.id] = kept
    # topics jump together: report one jump per distinct moment (within the tolerance)
    jumps.sort()
    merged: list[list[int]] = []
    for high, back, dropped in jumps:
        if merged and high - merged[-1][0] <= tol_ns:
            merged[-1][1] = max(merged[-1][1], back)
            merged[-1][2] += dropped
        else:
            merged.append([high, back, dropped])
    return [ClockJump((h - t0_ns) / 1e9, b / 1e9, d) for h, b, d in merged]


__all__ = ["CLOCK_JUMP_POLICIES", "CLOCK_JUMP_TOLERANCE", "ClockJump", "plan_clock_jumps"]
