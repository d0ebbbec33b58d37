"""Camera-only input from a folder of images (one image per frame, in file-name order).

:func:`open_image_folder` lists the images (:data:`IMAGE_SUFFIXES`, sorted by name) and reads the
first; :meth:`ImageFolderReader.frames` then streams :class:`~cogmap_core.frames.Frame` objects
as the bag reader does: the image (grey, or in colour when it is and the front end averages
colour, as a bag's), its motion from RatSLAM's visual odometry, the
ground truth of ``groundtruth.txt``. Frame times come from ``times.txt`` (one per image), else
``--fps`` (:mod:`.camera_common`; the files may also be named ``NAME.times.txt`` and
``NAME.groundtruth.txt`` beside the folder). An image that does not decode, or of another size
than the first, is skipped and counted.

Errors (one line each): a missing folder, a folder without images, no frame times, a times file
of another length, no image that decodes.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.datasets.camera_common import (
    CameraInfo,
    CameraReader,
    companion,
    frame_times,
    read_ground_truth,
)
from cogmap_core.datasets.jpeg import MAX_IMAGE_PIXELS, image_header
from cogmap_core.errors import InputFileError
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import averages_colour

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")


def image_files(folder: Path) -> list[Path]:
    """The folder's image files, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def _inside_or_beside(folder: Path, name: str) -> Path:
    inside = folder / name
    return inside if inside.exists() else companion(folder, name)


class ImageFolderReader(CameraReader):
    """An image folder; iterate :meth:`frames`."""

    format = "images"

    def __init__(
        self, folder: Path, fps: float | None = None, frontend: FrontEndConfig | None = None
    ) -> None:
        """List and check the images; see :func:`open_image_folder`."""
        if not folder.is_dir():
            raise InputFileError(f"{folder}: no such folder of images")
        self.files = image_files(folder)
        if not self.files:
            raise InputFileError(
                f"{folder}: no images in it ({', '.join(IMAGE_SUFFIXES)}); nothing to map"
            )
        times, source = frame_times(
            len(self.files),
            _inside_or_beside(folder, "times.txt"),
            fps,
            0.0,
            folder,
            "a times.txt in it (one time in s per image)",
        )
        gt_path = _inside_or_beside(folder, "groundtruth.txt")
        truth = read_ground_truth(gt_path) if gt_path.exists() else None
        super().__init__(folder, times, truth, frontend)
        self.colour = averages_colour(frontend)
        first = next((im for im in map(self._read, self.files[:50]) if im is not None), None)
        if first is None:
            raise InputFileError(f"{folder}: its first images do not decode; check the folder")
        self.info = CameraInfo(
            path=folder,
            frame_count=len(self.files),
            duration=float(times[-1] - times[0]),
            width=first.shape[1],
            height=first.shape[0],
            has_ground_truth=truth is not None,
            times_from=source,
        )

    def _images(self) -> Iterator[NDArray[np.uint8] | None]:
        for path in self.files:
            yield self._read(path)

    def _read(self, path: Path) -> NDArray[np.uint8] | None:
        return read_image(path, self.colour)


def read_image(path: Path, colour: bool = False) -> NDArray[np.uint8] | None:
    """The image at ``path``, or None when it does not decode.

    Grey ``(h, w)``; a colour image is ``(h, w, 3)``, blue, green, red, when ``colour``, else
    its luma. The file says which it is, never its pixels: a JPEG's or PNG's header
    (:func:`~cogmap_core.datasets.jpeg.image_header`), another format's own decoder
    (``cv2.IMREAD_ANYCOLOR``: a grey BMP, PGM or TIFF stays grey, a colour one that happens to
    be black is still in colour).
    """
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    if data.size == 0:
        return None
    header = image_header(data)
    if header is not None and header[0] * header[1] > MAX_IMAGE_PIXELS:
        return None  # refused from its header, never allocated (as in bags)
    flag = cv2.IMREAD_GRAYSCALE
    if colour and header is None:
        flag = cv2.IMREAD_ANYCOLOR
    elif colour and header is not None and header[2] == 3:
        flag = cv2.IMREAD_COLOR
    image = cv2.imdecode(data, flag)
    return image if image is not None and image.size else None


def open_image_folder(
    path: str | Path, fps: float | None = None, frontend: FrontEndConfig | None = None
) -> ImageFolderReader:
    """Open a folder of images as a camera-only input.

    Args:
        path: the folder.
        fps: the frame rate when there is no ``times.txt``.
        frontend: the visual odometry's settings (default: the iRat defaults).

    Raises:
        InputFileError: missing folder, no images, no frame times, bad times or ground-truth
            file, first images that do not decode.
        ParameterError: a bad ``fps``.

    """
    return ImageFolderReader(Path(path), fps, frontend)
