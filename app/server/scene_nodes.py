"""Growing arrays of items (vertices, edges, path segments) as scene nodes of a few hundred each.

Between two optimisations a map only grows at its end, so only the last chunk of each layer
changes: :class:`ChunkedNodes` compares every chunk with what it last sent and re-sends only the
chunks that differ (:class:`StreamStats` counts what was sent).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser

#: Items (vertices, edges, path segments) per scene node.
CHUNK = 512


@dataclass
class StreamStats:
    """What the streamer sent so far (for tests and benchmarks)."""

    updates: int = 0
    chunks_sent: int = 0
    chunks_removed: int = 0
    items_sent: int = 0
    bytes_sent: int = 0
    robot_updates: int = 0
    seconds: float = 0.0

    def copy(self) -> StreamStats:
        """A copy (to take differences)."""
        return StreamStats(**vars(self))


NodeFactory = Callable[[str, np.ndarray, np.ndarray | None], viser.SceneNodeHandle]
#: Puts new content (items, colours) into an existing node, in place.
NodeUpdater = Callable[[viser.SceneNodeHandle, np.ndarray, np.ndarray | None], None]


class ChunkedNodes:
    """A growing array of items shown as scene nodes of :data:`CHUNK` items each.

    :meth:`sync` sends only the chunks whose content differs from what was last sent, and removes
    chunks beyond the new length. A changed chunk is updated in place when ``updater`` is given
    (its points and colours replaced): a browser then keeps the node and its material, which is
    much cheaper than making a new one (a new line material is compiled, slowly without a GPU).
    """

    def __init__(
        self,
        name: str,
        factory: NodeFactory,
        stats: StreamStats,
        chunk: int = CHUNK,
        updater: NodeUpdater | None = None,
    ) -> None:
        """Manage nodes ``<name>/c0000``, ``<name>/c0001``, ... made by ``factory``."""
        self.name = name
        self.factory = factory
        self.updater = updater
        self.stats = stats
        self.chunk = chunk
        self._handles: list[viser.SceneNodeHandle] = []
        self._sent: list[tuple[np.ndarray, np.ndarray | None]] = []

    @property
    def num_chunks(self) -> int:
        """Chunks currently shown."""
        return len(self._handles)

    @property
    def num_items(self) -> int:
        """Items currently shown."""
        return sum(part.shape[0] for part, _ in self._sent)

    def items(self) -> np.ndarray | None:
        """All items currently shown, concatenated (None when empty)."""
        return np.concatenate([part for part, _ in self._sent]) if self._sent else None

    def colors(self) -> np.ndarray | None:
        """Their colours (None when empty or uncoloured)."""
        if not self._sent or self._sent[0][1] is None:
            return None
        return np.concatenate([c for _, c in self._sent if c is not None])

    def sync(self, items: np.ndarray, colors: np.ndarray | None = None, force: bool = False) -> int:
        """Show ``items`` (with per-item ``colors`` or none); return the chunks sent.

        ``force`` re-sends every chunk (the nodes' look changed).
        """
        n = items.shape[0]
        count = -(-n // self.chunk)
        sent = 0
        for c in range(count):
            lo, hi = c * self.chunk, min((c + 1) * self.chunk, n)
            part = items[lo:hi]
            cpart = None if colors is None else colors[lo:hi]
            if c < len(self._sent) and not force:
                old, old_colors = self._sent[c]
                if (
                    old.shape == part.shape
                    and np.array_equal(old, part)
                    and (cpart is None or np.array_equal(old_colors, cpart))
                ):
                    continue
            record = (part.copy(), None if cpart is None else cpart.copy())
            if c < len(self._handles):
                if self.updater is None:
                    self._handles[c] = self.factory(f"{self.name}/c{c:04d}", part, cpart)
                else:
                    self.updater(self._handles[c], part, cpart)
                self._sent[c] = record
            else:
                self._handles.append(self.factory(f"{self.name}/c{c:04d}", part, cpart))
                self._sent.append(record)
            sent += 1
            self.stats.items_sent += part.shape[0]
            self.stats.bytes_sent += part.nbytes + (0 if cpart is None else cpart.nbytes)
        for handle in self._handles[count:]:
            handle.remove()
            self.stats.chunks_removed += 1
        del self._handles[count:]
        del self._sent[count:]
        self.stats.chunks_sent += sent
        return sent

    def clear(self) -> None:
        """Remove every chunk."""
        for handle in self._handles:
            handle.remove()
        self.stats.chunks_removed += len(self._handles)
        self._handles.clear()
        self._sent.clear()
