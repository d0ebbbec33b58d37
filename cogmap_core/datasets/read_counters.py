"""What one pass over a bag met that did not stop it: counts, first times, warning lines."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields

from cogmap_core.datasets.jpeg import MAX_IMAGE_PIXELS

log = logging.getLogger(__name__)


@dataclass
class ReadCounters:
    """Counts of one pass over a bag (see the module docstring for the policy)."""

    frames: int = 0
    undecodable_images: int = 0
    image_size_changes: int = 0
    image_stamps_backwards: int = 0
    corrupt_messages: int = 0
    nonfinite_odometry: int = 0
    odometry_stamps_backwards: int = 0
    odometry_clock_resets: int = 0
    odometry_gaps: int = 0
    nonfinite_ground_truth: int = 0
    ground_truth_stamps_backwards: int = 0
    frames_without_ground_truth: int = 0
    corrupt_images: int = 0
    clock_jumps: int = 0
    clock_jump_messages_dropped: int = 0
    corrupt_chunks: int = 0
    oversized_images: int = 0
    first_seen: dict[str, float] = field(default_factory=dict)

    def note(self, name: str, time: float) -> None:
        """Count one event of kind ``name`` at data time ``time`` (s)."""
        setattr(self, name, getattr(self, name) + 1)
        if name not in self.first_seen:
            self.first_seen[name] = time
            log.warning("%s (first at t=%.2f s)", WARNING_TEXT[name], time)

    def warnings(self) -> list[str]:
        """One line per kind of problem met, with its count and first time."""
        out = []
        for f in fields(self):
            if f.name in ("frames", "first_seen", *DESCRIBED_AT_OPEN):
                continue
            n = getattr(self, f.name)
            if n:
                first = self.first_seen.get(f.name, float("nan"))
                out.append(f"{n} x {WARNING_TEXT[f.name]} (first at t={first:.2f} s)")
        return out


WARNING_TEXT = {
    "undecodable_images": "undecodable camera image skipped",
    "image_size_changes": "camera image of a different size skipped",
    "image_stamps_backwards": "camera frame stamped before the previous one skipped",
    "corrupt_messages": "unreadable (corrupt) message skipped",
    "nonfinite_odometry": "odometry with NaN/inf velocity skipped",
    "odometry_stamps_backwards": "odometry stamped before the previous one skipped",
    "odometry_clock_resets": "odometry clock reset accepted",
    "odometry_gaps": "odometry gap longer than the limit (no motion integrated over it)",
    "nonfinite_ground_truth": "ground-truth pose with NaN/inf skipped",
    "ground_truth_stamps_backwards": "ground-truth pose stamped before the previous one skipped",
    "frames_without_ground_truth": "frame without ground truth nearby",
    "corrupt_images": "camera image with corrupt JPEG data (decoded scrambled) skipped",
    "clock_jumps": "clock jump back (see the opening warning)",
    "clock_jump_messages_dropped": "message dropped at a clock jump",
    "corrupt_chunks": "corrupt bag data: reading stopped there, the frames before it kept",
    "oversized_images": f"camera image larger than {MAX_IMAGE_PIXELS:,} pixels skipped undecoded",
}


#: Counted per pass but described by :attr:`BagReader.open_warnings` (found when opening).
DESCRIBED_AT_OPEN = ("clock_jumps", "clock_jump_messages_dropped")


__all__ = ["DESCRIBED_AT_OPEN", "WARNING_TEXT", "ReadCounters"]
