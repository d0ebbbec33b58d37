"""The open panel (shared): replay another bag, video, image folder or log of the data folders.

Only what the data folders list can be opened (:class:`~app.server.files.DataFolders`); the
chosen input is checked and opened on a thread of its own (one at a time), and only then does
the page swap its replay for one of the new input (:meth:`OpenHost.switch_input`), for everyone.
"""

from __future__ import annotations

import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import viser

from app.server.panels import note_html
from app.server.validation import GuiGate, choice, click
from cogmap_core.errors import CogmapError
from cogmap_core.sources.detect import KINDS, LogOptions, Source, open_source

if TYPE_CHECKING:
    from app.inputs import InputOptions
    from app.server.files import DataFile, DataFolders, Scrubber

#: What the bag list shows when the data folders hold no bag.
NO_BAG = "(no bag in the data folders)"


@dataclass(frozen=True, slots=True)
class OpenPanel:
    """The open panel's handles ("Open another bag or log — shared")."""

    bag_dropdown: viser.GuiDropdownHandle[str]
    refresh_button: viser.GuiButtonHandle
    open_button: viser.GuiButtonHandle
    open_md: viser.GuiHtmlHandle


def build_open(gui: viser.GuiApi, list_names: Callable[[], tuple[str, ...]]) -> OpenPanel:
    """Add the open folder (folded), its list the names ``list_names`` gives."""
    with gui.add_folder("Open another bag or log — shared", expand_by_default=False):
        names = list_names()
        bag_dropdown = gui.add_dropdown("bag or log", names, initial_value=names[0])
        refresh_button = gui.add_button("refresh the list", icon=viser.Icon.REFRESH)
        open_button = gui.add_button("open", icon=viser.Icon.FOLDER_OPEN)
        open_md = gui.add_html(
            '<div class="cogmap-note" id="cogmap-open">A bag, or a log of odometry and place '
            "recognition (TUC or CSV), of the server's data folders; the replay starts over "
            "with it, for everyone.</div>"
        )
    return OpenPanel(bag_dropdown, refresh_button, open_button, open_md)


class OpenHost(Protocol):
    """What the open panel uses of the page: how inputs are read, and the replay's swap."""

    input_options: InputOptions

    def switch_input(self, chosen: DataFile, reader: Source) -> None:
        """Replay ``chosen`` (already open as ``reader``) instead of the current input."""

    def sync_play_button(self) -> None:
        """Label the play button for the new replay."""


class InputChooser:
    """What the open panel's controls do (module doc); ``panel`` holds them."""

    def __init__(
        self, gui: viser.GuiApi, data: DataFolders, scrubber: Scrubber, host: OpenHost
    ) -> None:
        """Build the panel listing ``data``'s inputs; errors are told with ``scrubber``."""
        self.data = data
        self.scrubber = scrubber
        self.host = host
        self._bags: dict[str, DataFile] = {}
        self._busy = threading.Lock()  # one input opened at a time
        self.opening: threading.Thread | None = None
        self.panel = build_open(gui, self._list_bags)
        self.panel.refresh_button.on_click(lambda _: self.refresh_bags())
        self.panel.open_button.on_click(lambda _: self.open_chosen())

    def guard(self, gate: GuiGate) -> None:
        """Check every value a client can send to the panel's controls."""
        p = self.panel
        gate.guard(p.refresh_button, click())
        gate.guard(p.open_button, click())
        gate.guard(p.bag_dropdown, choice(lambda: tuple(p.bag_dropdown.options)))

    def _say(self, text: str, error: bool = False) -> None:
        self.panel.open_md.content = note_html("cogmap-open", text, error)

    def _list_bags(self) -> tuple[str, ...]:
        """List the bags of the data folders; the dropdown's options (never empty)."""
        self._bags = {f.name: f for f in self.data.listing()}
        return tuple(self._bags) or (NO_BAG,)

    def refresh_bags(self) -> list[str]:
        """List the bags of the data folders in the dropdown again; returns their names."""
        names = self._list_bags()
        dropdown = self.panel.bag_dropdown
        if tuple(dropdown.options) != names:
            dropdown.options = names
        if dropdown.value not in names:
            dropdown.value = names[0]
        return list(self._bags)

    def open_chosen(self) -> threading.Thread | None:
        """The open button: open the chosen bag on a thread of its own (one at a time)."""
        name = self.panel.bag_dropdown.value
        with self._busy:
            if self.opening is not None and self.opening.is_alive():
                self._say("another bag is being opened; wait for it", error=True)
                return None
            self._say(f"opening {name} …")
            thread = threading.Thread(
                target=self.open_bag, args=(name,), name="cogmap-open-bag", daemon=True
            )
            thread.start()
            self.opening = thread
        return thread

    def open_bag(self, name: str) -> bool:
        """Replay the input listed as ``name`` (in the data folders); errors go to the page.

        Only the names of :meth:`refresh_bags`' list are opened; anything else -- a path, a
        missing file, a folder not listed -- gets the same one line. The file is checked again
        (a regular file inside its folder, not too large; an image folder's images regular
        files) and opened by its resolved path, then checked (a bag, video or image folder with
        camera frames, or a log of odometry and place recognition read whole, as
        ``cogmap serve FILE`` reads it) before the current replay is replaced. A camera input
        after a log (or a log after one) starts from its kind's default parameters.
        """
        chosen = self._bags.get(name)
        if chosen is None:
            shown = name if len(name) <= 80 else name[:77] + "…"
            self._say(
                f"not opened: {shown!r} is not one of the bags in the data folders "
                "(refresh the list to see new ones)",
                error=True,
            )
            return False
        problem = None
        reader = None
        # opened once here, to refuse it before the running replay stops (the reader names what
        # is wrong: neither a ROS 1 bag nor a ROS 2 bag, ...), then handed over to the new replay
        options = self.host.input_options
        try:
            chosen = self.data.check(chosen)
            if KINDS[chosen.kind].has_camera:  # a bag, video or image folder: serve's options
                reader = open_source(  # (--odometry, --fps, topics, and the input's front end)
                    chosen.path,
                    chosen.kind,
                    topics=options.topics,
                    image_scale=options.image_scale,
                    camera=options.camera_for(chosen.path),
                )
            else:  # a log: read (and checked) whole, as cogmap serve FILE reads it
                reader = open_source(chosen.path, chosen.kind, log=LogOptions())
            frames = reader.info.frame_count
            if frames == 0:
                problem = (
                    f"{name} has no camera frames on the image topic"
                    if chosen.kind == "bag"
                    else f"{name} has no camera frames"
                    if KINDS[chosen.kind].has_camera
                    else f"{name} has no odometry to map"
                )
        except CogmapError as exc:
            problem = self.scrubber.scrub(str(exc))
        except Exception as exc:
            traceback.print_exc()
            problem = f"cannot open {name}: {type(exc).__name__}"
        if problem is not None:
            if reader is not None:
                reader.close()
            self._say(f"not opened: {problem}", error=True)
            return False
        assert reader is not None
        self.host.switch_input(chosen, reader)
        what = "frames" if KINDS[chosen.kind].has_camera else "steps"
        self._say(f"opened {name} ({frames} {what}); replaying it for everyone")
        self.host.sync_play_button()
        return True
