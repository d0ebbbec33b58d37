"""The export panel: download the shown map (g2o), summary.json, sizes.csv; save an HTML replay.

What is exported is the asking viewer's: the map it shows, the replay up to now. The files are
made by :mod:`app.server.export` (those of ``cogmap run``); an HTML replay is rendered on a thread
of its own (one at a time) into the server's export folder and sent to the browser.
"""

from __future__ import annotations

import dataclasses
import threading
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import viser

from app.server.export import (
    default_replay_name,
    g2o_bytes,
    save_html_replay,
    sizes_csv_bytes,
    summary_bytes,
    summary_inputs,
)
from app.server.panels import note_html
from app.server.validation import GuiGate, click, text
from cogmap_core.cognitive_map import MapMode
from cogmap_core.errors import CogmapError

if TYPE_CHECKING:
    from app.server.files import DataFolders, ExportFolder, Scrubber
    from app.server.replay import Replay


@dataclass(frozen=True, slots=True)
class ExportPanel:
    """The export panel's handles ("Export")."""

    g2o_button: viser.GuiButtonHandle
    summary_button: viser.GuiButtonHandle
    sizes_button: viser.GuiButtonHandle
    replay_path: viser.GuiTextHandle
    replay_button: viser.GuiButtonHandle
    export_md: viser.GuiHtmlHandle


def build_export(gui: viser.GuiApi) -> ExportPanel:
    """Add the export folder (the replay's name proposed for the compact map)."""
    with gui.add_folder("Export"):
        g2o_button = gui.add_button("download map (.g2o)", icon=viser.Icon.DOWNLOAD)
        summary_button = gui.add_button("download summary.json", icon=viser.Icon.DOWNLOAD)
        sizes_button = gui.add_button("download sizes.csv", icon=viser.Icon.DOWNLOAD)
        replay_path = gui.add_text(  # a file name: saved in the server's export folder
            "replay name",
            default_replay_name(MapMode.COMPACT),
            hint="a file name; the replay is saved in the server's export folder and sent "
            "to your browser",
        )
        replay_button = gui.add_button("save HTML replay", icon=viser.Icon.DEVICE_FLOPPY)
        export_md = gui.add_html("")
    return ExportPanel(
        g2o_button, summary_button, sizes_button, replay_path, replay_button, export_md
    )


def export_message(text_: str, error: bool = False) -> str:
    """The panel's message (``#cogmap-export``)."""
    return note_html("cogmap-export", text_, error)


class ExportHost(Protocol):
    """What the export panel uses of the page: the replay, its folders, the viewers' maps."""

    server: viser.ViserServer
    replay: Replay
    data: DataFolders
    exports: ExportFolder
    scrubber: Scrubber
    static_dir: Path | None

    def modes_of(self, client: viser.ClientHandle | None) -> tuple[MapMode, ...]:
        """The maps ``client`` shows (the page's default view's without a client)."""


class ExportControls:
    """What the export panel's controls do (module doc); ``panel`` holds them."""

    def __init__(self, panel: ExportPanel, host: ExportHost) -> None:
        """Wire ``panel``'s buttons to ``host``'s replay."""
        self.panel = panel
        self.host = host
        self._busy = threading.Lock()  # one HTML replay saved at a time
        self.saving: threading.Thread | None = None
        panel.g2o_button.on_click(lambda event: self.download(event.client, "g2o"))
        panel.summary_button.on_click(lambda event: self.download(event.client, "summary"))
        panel.sizes_button.on_click(lambda event: self.download(event.client, "sizes"))
        panel.replay_button.on_click(lambda event: self.save_replay(event.client))

    def guard(self, gate: GuiGate) -> None:
        """Check every value a client can send to the panel's controls."""
        p = self.panel
        for button in (p.g2o_button, p.summary_button, p.sizes_button, p.replay_button):
            gate.guard(button, click())
        gate.guard(p.replay_path, text(max_length=200))

    def _say(self, text_: str, error: bool = False) -> None:
        self.panel.export_md.content = export_message(text_, error)

    def download(self, client: viser.ClientHandle | None, what: str) -> None:
        """Send ``client`` (None: every browser) the ``g2o``, ``summary`` or ``sizes`` file."""
        host = self.host
        try:
            inputs = None
            with host.replay.lock:
                mode = host.modes_of(client)[0]
                if what == "g2o":
                    name, content = f"{mode.value}.g2o", g2o_bytes(host.replay.session.maps[mode])
                elif what == "summary":
                    inputs = summary_inputs(host.replay)  # a copy: its figures need no lock
                else:
                    name, content = "sizes.csv", sizes_csv_bytes(host.replay)
            if inputs is not None:  # (the bag named as the page names it, not by its server path)
                inputs = dataclasses.replace(inputs, dataset=host.data.shown(inputs.dataset))
                name, content = "summary.json", summary_bytes(inputs)
        except Exception as exc:
            traceback.print_exc()
            self._say(f"export failed: {host.scrubber.scrub(str(exc))}", error=True)
            return
        self._say(f"sent {name} ({len(content)} bytes)")
        targets = [client] if client is not None else list(host.server.get_clients().values())
        for c in targets:
            c.send_file_download(name, content, save_immediately=True)

    def save_replay(self, client: viser.ClientHandle | None) -> threading.Thread | None:
        """Save the HTML replay of ``client``'s view in the export folder and send it to ``client``.

        The name is the box's, made safe (:func:`~app.server.files.safe_name`); one replay is
        rendered at a time. Returns the thread rendering it (None when refused at once).
        """
        host = self.host
        target = host.exports.target(self.panel.replay_path.value)
        modes = host.modes_of(client)
        with self._busy:
            if self.saving is not None and self.saving.is_alive():
                self._say("a replay is being saved; try again when it is done", error=True)
                return None
            self._say(f"saving the HTML replay as {target.name} in the export folder …")

            def send(page: bytes) -> None:
                if client is not None:
                    client.send_file_download(target.name, page, save_immediately=True)

            def work() -> None:
                try:
                    host.exports.prepare(target)
                    save_html_replay(
                        host.replay, modes, target, static_dir=host.static_dir, sent=send
                    )
                except CogmapError as exc:
                    self._say(f"replay not saved: {host.scrubber.scrub(str(exc))}", True)
                    return
                except Exception as exc:
                    traceback.print_exc()
                    self._say(f"replay not saved: {type(exc).__name__}", True)
                    return
                self._say(
                    f"saved the HTML replay as {target.name} in the export folder"
                    + (" and sent it to your browser" if client is not None else "")
                )

            thread = threading.Thread(target=work, name="cogmap-html-replay", daemon=True)
            thread.start()
            self.saving = thread
        return thread

    def follow_view(self, mode: MapMode) -> None:
        """Propose the replay's name for ``mode`` (unless the name was typed by someone)."""
        path = self.panel.replay_path
        if path.value in {default_replay_name(m) for m in MapMode}:  # keep a name the user typed
            path.value = default_replay_name(mode)
