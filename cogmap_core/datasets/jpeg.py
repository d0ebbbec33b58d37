"""JPEG decoding that notices corrupt data libjpeg only warns about.

A JPEG whose entropy-coded data is damaged often still decodes: libjpeg prints a warning such
as ``Corrupt JPEG data: premature end of data segment`` or ``Corrupt JPEG data: 22 extraneous
bytes before marker 0xd9`` to the process's standard error and returns a scrambled image.
OpenCV's ``imdecode`` does not report these warnings, so :class:`JpegDecoder` catches them:
while ``imdecode`` runs, file descriptor 2 points to a private pipe; what libjpeg wrote there
tells whether the image is corrupt, and anything else written in that moment (by another
thread) is passed on to the real standard error. This costs a few microseconds per image
(about 1 % of decoding a 416x240 frame). Redirections are serialised by a process-wide lock.

Where file descriptor 2 cannot be redirected (closed, or no pipes), images are decoded without
the check. Damage that libjpeg itself does not notice (bytes overwritten so that the Huffman
codes stay valid and end where they should: a fraction of random overwrites) goes through.

Before anything is decoded, the size the image declares is read from its header (the JPEG
frame header, SOF; a PNG's IHDR chunk) by :func:`image_size`: an image of more than
:data:`MAX_IMAGE_PIXELS` pixels is refused (:class:`ImageTooLarge`) without allocating it (a
4 kB JPEG can declare 65000 x 65000 pixels, which libjpeg would spend gigabytes and most of a
minute on), and data that is neither JPEG nor PNG is not handed to OpenCV (which would also
decode TIFF, WebP, OpenEXR, ... with their own decoders) but reported undecodable.

Colour. The same header says whether the image is in colour (a JPEG of three components, a PNG
of colour type RGB, RGBA or palette: :func:`image_header`). A decoder given a ``colour_flag``
decodes colour images with it (``cv2.IMREAD_COLOR``: blue, green, red, as OpenRatSLAM receives a
``bgr8`` image) and grey ones with its ``flag``, so a grey camera costs nothing more.
"""

from __future__ import annotations

import contextlib
import os
import threading

import cv2
import numpy as np
from numpy.typing import NDArray

#: Beginnings of libjpeg's warnings that mean the image data is damaged (jerror.h, JWRN_*).
CORRUPTION_WARNINGS: tuple[str, ...] = (
    "Corrupt JPEG data",
    "Premature end of JPEG file",
    "Invalid SOS parameters for sequential JPEG",
    "Inconsistent progression sequence",
)

_FD2_LOCK = threading.Lock()

#: The largest camera image decoded, in pixels (width x height as its header declares them):
#: 16.8 million, e.g. 4096 x 4096 or a 5472 x 3078 (17:10) frame; iRat frames have 99,840.
MAX_IMAGE_PIXELS = 4096 * 4096

_JPEG_SOI = b"\xff\xd8"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, extended, progressive, lossless; Huffman or arithmetic).
_SOF_MARKERS = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD,
                          0xCE, 0xCF})  # fmt: skip
#: Markers without a length field (restart markers, SOI, TEM).
_STANDALONE = frozenset({0x01, 0xD8, *range(0xD0, 0xD8)})


class ImageTooLarge(ValueError):
    """An image whose header declares more than :data:`MAX_IMAGE_PIXELS` pixels."""

    def __init__(self, width: int, height: int) -> None:
        """Record the declared size."""
        super().__init__(
            f"image of {width} x {height} pixels is larger than the {MAX_IMAGE_PIXELS:,} pixels "
            "decoded"
        )
        self.width = width
        self.height = height


def image_size(data: bytes | NDArray[np.uint8]) -> tuple[int, int] | None:
    """``(width, height)`` declared by a JPEG or PNG header, or None (neither, or no size found).

    Reads the header only: the JPEG markers up to the first start-of-frame (each segment's
    length is skipped, never its content), or the PNG's IHDR chunk. A JPEG whose frame header
    gives height 0 (the height follows in a DNL marker, which no camera writes) has no size here.
    """
    header = image_header(data)
    return None if header is None else (header[0], header[1])


def image_header(data: bytes | NDArray[np.uint8]) -> tuple[int, int, int] | None:
    """``(width, height, channels)`` declared by a JPEG or PNG header, or None (see image_size).

    ``channels`` is 3 for a colour image (a JPEG of three components; a PNG of colour type RGB,
    RGBA or palette, decoded as blue, green, red), 1 for a grey one (a JPEG of one component, a
    grey PNG with or without alpha), and the JPEG's component count otherwise (4: CMYK).
    """
    buf = memoryview(data).cast("B") if not isinstance(data, bytes) else memoryview(data)
    n = len(buf)
    if n >= 26 and bytes(buf[:8]) == _PNG_SIGNATURE and bytes(buf[12:16]) == b"IHDR":
        width = int.from_bytes(buf[16:20], "big")
        height = int.from_bytes(buf[20:24], "big")
        channels = 3 if buf[25] in (2, 3, 6) else 1
        return (width, height, channels) if width and height else None
    if n < 4 or bytes(buf[:2]) != _JPEG_SOI:
        return None
    pos = 2
    while pos + 4 <= n:
        if buf[pos] != 0xFF:
            return None  # not at a marker: damaged
        marker = buf[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _STANDALONE:
            pos += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no frame header before
            return None
        length = int.from_bytes(buf[pos + 2 : pos + 4], "big")
        if length < 2:
            return None
        if marker in _SOF_MARKERS:
            if pos + 10 > n or length < 8:
                return None
            height = int.from_bytes(buf[pos + 5 : pos + 7], "big")
            width = int.from_bytes(buf[pos + 7 : pos + 9], "big")
            components = int(buf[pos + 9])
            return (width, height, components) if width and height else None
        pos += 2 + length
    return None


class JpegDecoder:
    """``cv2.imdecode`` plus libjpeg's corruption warnings.

    Args:
        flag: the ``cv2.IMREAD_*`` flag (e.g. ``cv2.IMREAD_REDUCED_GRAYSCALE_4``).
        colour_flag: the flag for images whose header says they are in colour (e.g.
            ``cv2.IMREAD_COLOR``: a ``(height, width, 3)`` image, blue, green, red); None
            decodes every image with ``flag``.

    """

    def __init__(self, flag: int, colour_flag: int | None = None) -> None:
        """Open the private pipe (decoding without the check if that fails)."""
        self.flag = flag
        self.colour_flag = colour_flag
        self._read_fd: int | None = None
        self._write_fd: int | None = None
        try:
            r, w = os.pipe()
        except OSError:
            return
        try:
            os.set_blocking(r, False)
        except (OSError, AttributeError):  # pragma: no cover - platforms without it
            os.close(r)
            os.close(w)
            return
        self._read_fd, self._write_fd = r, w

    @property
    def checks(self) -> bool:
        """Whether libjpeg's warnings are being caught."""
        return self._write_fd is not None

    def decode(self, data: NDArray[np.uint8]) -> tuple[NDArray[np.uint8] | None, str | None]:
        """Decode ``data``; returns ``(image or None, libjpeg's corruption warning or None)``.

        Data that is neither a JPEG nor a PNG with a size in its header is not decoded (None).

        Raises:
            ImageTooLarge: the header declares more than :data:`MAX_IMAGE_PIXELS` pixels.

        """
        header = image_header(data)
        if header is None:
            return None, None
        width, height, channels = header
        if width * height > MAX_IMAGE_PIXELS:
            raise ImageTooLarge(width, height)
        flag = self.flag
        if self.colour_flag is not None and channels == 3:
            flag = self.colour_flag
        if self._write_fd is None:
            return cv2.imdecode(data, flag), None
        with _FD2_LOCK:
            try:
                saved = os.dup(2)
            except OSError:  # no standard error to redirect
                return cv2.imdecode(data, flag), None
            try:
                os.dup2(self._write_fd, 2)
                try:
                    image = cv2.imdecode(data, flag)
                finally:
                    os.dup2(saved, 2)
            finally:
                os.close(saved)
        return image, self._collect()

    def _collect(self) -> str | None:
        """Read what was written to the pipe; pass on what is not a corruption warning."""
        assert self._read_fd is not None
        chunks: list[bytes] = []
        while True:
            try:
                chunk = os.read(self._read_fd, 65536)
            except BlockingIOError:
                break
            if not chunk:
                break
            chunks.append(chunk)
        if not chunks:
            return None
        warning: str | None = None
        passed_on: list[str] = []
        for line in b"".join(chunks).decode("utf-8", "replace").splitlines(keepends=True):
            text = line.strip()
            if warning is None and text.startswith(CORRUPTION_WARNINGS):
                warning = text
            elif not text.startswith(CORRUPTION_WARNINGS):
                passed_on.append(line)
        if passed_on:
            with contextlib.suppress(OSError):
                os.write(2, "".join(passed_on).encode())
        return warning

    def close(self) -> None:
        """Close the pipe (idempotent)."""
        for fd in (self._read_fd, self._write_fd):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._read_fd = self._write_fd = None

    def __del__(self) -> None:
        self.close()
