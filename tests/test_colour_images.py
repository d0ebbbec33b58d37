"""Colour camera images (issue 26, part 2a): in OpenRatSLAM's arithmetic a colour image's view
template and visual-odometry profiles average blue, green and red as OpenRatSLAM does with a
``bgr8`` image (``local_view_match.cpp`` / ``visual_odometry.cpp``: a block's sum of B + G + R,
divided by 255 * 3, then by its pixels) -- exactly; a grey camera is decoded and averaged as
before; cogmap's whole-crop setting takes a colour image's luma. Bags, image folders and the
decoder, videos, the camera panel and the page's list of inputs, on small colour images."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from app.inputs import InputOptions
from app.server.panels.live_figures import camera_rgb
from cogmap_core.datasets.bag_writer import IratBagWriter
from cogmap_core.datasets.image_folder import open_image_folder, read_image
from cogmap_core.datasets.jpeg import JpegDecoder, image_header
from cogmap_core.datasets.rosbag_reader import open_bag
from cogmap_core.datasets.video_reader import open_video
from cogmap_core.frontend import FrontEndConfig, LocalViewCells
from cogmap_core.frontend.config import COGMAP_ARITHMETIC
from cogmap_core.frontend.local_view import VALUE_SCALE, averages_colour
from cogmap_core.frontend.visual_odometry import VisualOdometry
from cogmap_core.sources.detect import CameraOptions

OPENRATSLAM = FrontEndConfig()  # its arithmetic is the default
WHOLE = FrontEndConfig(**COGMAP_ARITHMETIC)


def colour_image(seed: int, height: int = 240, width: int = 416) -> np.ndarray:
    """A smooth random blue-green-red image with some noise (a camera frame's kind of content)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (height // 10, width // 10, 3), dtype=np.uint8)
    smooth = cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC).astype(float)
    return np.clip(smooth + rng.normal(0, 8, smooth.shape), 0, 255).astype(np.uint8)


def openratslam_block_means(image: np.ndarray, config: FrontEndConfig) -> np.ndarray:
    """``convert_view_to_view_template``'s ``current_view`` before normalisation, as its loops
    compute it (blocks of whole pixels from the crop's first column and row; a ``bgr8`` pixel
    adds ``(double)B + (double)G + (double)R``; then ``/= 255.0 * 3.0`` and ``/= block
    pixels``), in double precision, for an image at the reference size."""
    x0, x1 = config.image_crop_x_min, config.image_crop_x_max
    y0, y1 = config.image_crop_y_min, config.image_crop_y_max
    bx = (x1 - x0) // config.template_x_size
    by = (y1 - y0) // config.template_y_size
    colour = image.ndim == 3
    view = np.zeros((config.template_y_size, config.template_x_size))
    for yb in range(config.template_y_size):
        for xb in range(config.template_x_size):
            total = 0.0
            for x in range(x0 + xb * bx, x0 + (xb + 1) * bx):
                for y in range(y0 + yb * by, y0 + (yb + 1) * by):
                    if colour:
                        b, g, r = (float(v) for v in image[y, x])
                        total += b + g + r
                    else:
                        total += float(image[y, x])
            total /= 255.0 * 3.0 if colour else 255.0
            total /= bx * by
            view[yb, xb] = total
    return view


def test_a_colour_template_averages_blue_green_and_red_exactly_as_openratslam() -> None:
    lv = LocalViewCells(OPENRATSLAM)
    image = colour_image(1)
    reference = openratslam_block_means(image, OPENRATSLAM)
    # the template is OpenRatSLAM's normalisation of these means, kept in 2^-20 steps
    expected = lv._normalised_blocks(reference)
    template = lv.make_template(image)
    assert template.dtype == np.int32 and template.shape == (20, 60)
    np.testing.assert_array_equal(template, expected)
    # not the luma's template (what cogmap decoded before)
    luma = lv.make_template(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    assert np.abs(luma - template).max() > VALUE_SCALE / 100
    # a grey image given as three equal channels: the grey image's template, to the bit
    grey = image[:, :, 1].copy()
    np.testing.assert_array_equal(lv.make_template(np.dstack([grey] * 3)), lv.make_template(grey))
    np.testing.assert_array_equal(
        lv._normalised_blocks(openratslam_block_means(grey, OPENRATSLAM)), lv.make_template(grey)
    )


def test_the_whole_crop_setting_takes_a_colour_image_s_luma() -> None:
    assert averages_colour(OPENRATSLAM) and averages_colour(None)
    assert not averages_colour(WHOLE)
    lv = LocalViewCells(WHOLE)
    image = colour_image(2)
    np.testing.assert_array_equal(
        lv.make_template(image), lv.make_template(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    )


def test_visual_odometry_profiles_average_blue_green_and_red() -> None:
    image = colour_image(3)
    vo = VisualOdometry(OPENRATSLAM)
    vtrans, vrot = vo.profiles(image)
    (rows_t, cols_t), (rows_r, cols_r) = vo._strips_for(image.shape[:2])
    for profile, rows, cols in ((vtrans, rows_t, cols_t), (vrot, rows_r, cols_r)):
        strip = image[rows, cols].astype(np.float64)
        expected = strip.sum(axis=(0, 2)) / (255.0 * 3.0) / strip.shape[0]
        np.testing.assert_array_equal(profile, expected)
    grey = image[:, :, 2].copy()
    for a, b in zip(vo.profiles(np.dstack([grey] * 3)), vo.profiles(grey), strict=True):
        np.testing.assert_array_equal(a, b)
    luma = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    whole = VisualOdometry(WHOLE)
    for a, b in zip(whole.profiles(image), whole.profiles(luma), strict=True):
        np.testing.assert_array_equal(a, b)


def _jpeg(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return data.tobytes()


def test_the_decoder_decodes_a_colour_jpeg_in_colour_only_when_asked() -> None:
    image = colour_image(4)
    colour, grey = _jpeg(image), _jpeg(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    assert image_header(colour) == (416, 240, 3) and image_header(grey) == (416, 240, 1)
    ok, png = cv2.imencode(".png", image)
    assert ok and image_header(png.tobytes()) == (416, 240, 3)
    both = JpegDecoder(cv2.IMREAD_GRAYSCALE, cv2.IMREAD_COLOR)
    plain = JpegDecoder(cv2.IMREAD_GRAYSCALE)
    try:
        decoded, warning = both.decode(np.frombuffer(colour, np.uint8))
        assert warning is None and decoded is not None and decoded.shape == (240, 416, 3)
        np.testing.assert_array_equal(decoded, cv2.imdecode(np.frombuffer(colour, np.uint8), 1))
        assert both.decode(np.frombuffer(grey, np.uint8))[0].shape == (240, 416)  # type: ignore[union-attr]
        assert plain.decode(np.frombuffer(colour, np.uint8))[0].shape == (240, 416)  # type: ignore[union-attr]
    finally:
        both.close()
        plain.close()


def _colour_bag(path: Path, images: list[np.ndarray]) -> None:
    with IratBagWriter(path) as bag:
        for k, image in enumerate(images):
            t = 1_000_000_000 + k * 100_000_000
            bag.write_odometry(t - 50_000_000, 0.1, 0.0)
            bag.write_odometry(t, 0.1, 0.0)
            bag.write_image(t, _jpeg(image))


def test_a_bag_of_colour_jpegs_gives_colour_frames_in_openratslam_s_arithmetic(
    tmp_path: Path,
) -> None:
    images = [colour_image(10 + k) for k in range(4)]
    bag = tmp_path / "colour.bag"
    _colour_bag(bag, images)
    with open_bag(bag) as reader:
        frames = list(reader.frames())
    assert len(frames) == 4 and reader.colour
    lv = LocalViewCells(OPENRATSLAM)
    for frame, image in zip(frames, images, strict=True):
        decoded = cv2.imdecode(np.frombuffer(_jpeg(image), np.uint8), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(frame.image, decoded)  # blue, green, red as decoded
        np.testing.assert_array_equal(
            lv.make_template(frame.image),
            lv._normalised_blocks(openratslam_block_means(decoded, OPENRATSLAM)),
        )
    with open_bag(bag, frontend=WHOLE) as reader:  # cogmap's whole crop: the luma, as before
        grey = list(reader.frames())
    assert not reader.colour
    for frame, image in zip(grey, images, strict=True):
        np.testing.assert_array_equal(
            frame.image, cv2.imdecode(np.frombuffer(_jpeg(image), np.uint8), 0)
        )
    with open_bag(bag, image_scale=2) as reader:  # decoded at half size, still in colour
        half = list(reader.frames())
    for frame, image in zip(half, images, strict=True):
        data = np.frombuffer(_jpeg(image), np.uint8)
        np.testing.assert_array_equal(frame.image, cv2.imdecode(data, cv2.IMREAD_REDUCED_COLOR_2))
        assert frame.image.shape == (120, 208, 3)


def test_a_bag_of_grey_jpegs_reads_as_before_and_may_mix_with_colour(tmp_path: Path) -> None:
    colour = [colour_image(30 + k) for k in range(4)]
    grey = [cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in colour]
    bag = tmp_path / "grey.bag"
    _colour_bag(bag, grey)
    for frontend in (OPENRATSLAM, WHOLE):  # a grey camera: grey frames whatever the arithmetic
        with open_bag(bag, frontend=frontend) as reader:
            frames = list(reader.frames())
        for frame, image in zip(frames, grey, strict=True):
            decoded = cv2.imdecode(np.frombuffer(_jpeg(image), np.uint8), cv2.IMREAD_GRAYSCALE)
            np.testing.assert_array_equal(frame.image, decoded)
    # grey and colour frames of one size in one bag: each averaged as it is, none skipped
    mixed = tmp_path / "mixed.bag"
    _colour_bag(mixed, [colour[0], grey[1], colour[2], grey[3]])
    with open_bag(mixed) as reader:
        frames = list(reader.frames())
        assert reader.counters.image_size_changes == 0
    assert [f.image.ndim for f in frames] == [3, 2, 3, 2]


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_an_image_folder_of_colour_images(tmp_path: Path, suffix: str) -> None:
    folder = tmp_path / "images"
    folder.mkdir()
    images = [colour_image(20 + k) for k in range(3)]
    for k, image in enumerate(images):
        assert cv2.imwrite(str(folder / f"{k:03d}{suffix}"), image)
    reader = open_image_folder(folder, fps=10.0)
    frames = list(reader.frames())
    assert [f.image.shape for f in frames] == [(240, 416, 3)] * 3
    if suffix == ".png":  # lossless: the very pixels written
        for frame, image in zip(frames, images, strict=True):
            np.testing.assert_array_equal(frame.image, image)
    grey = list(open_image_folder(folder, fps=10.0, frontend=WHOLE).frames())
    assert [f.image.shape for f in grey] == [(240, 416)] * 3
    path = folder / f"000{suffix}"
    np.testing.assert_array_equal(grey[0].image, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    # a grey image stays grey whatever the setting
    cv2.imwrite(str(tmp_path / "grey.png"), images[0][:, :, 0])
    assert read_image(tmp_path / "grey.png", colour=True).shape == (240, 416)  # type: ignore[union-attr]


def test_other_formats_are_grey_or_colour_as_their_files_say(tmp_path: Path) -> None:
    image = colour_image(25)
    black = np.zeros_like(image)
    for suffix in (".bmp", ".tif", ".ppm"):
        for name, pixels in (("colour", image), ("black", black)):
            path = tmp_path / f"{name}{suffix}"
            assert cv2.imwrite(str(path), pixels)
            # a colour file is in colour, even one whose pixels are all grey (black)
            np.testing.assert_array_equal(read_image(path, colour=True), pixels)  # type: ignore[arg-type]
            luma = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            np.testing.assert_array_equal(read_image(path), luma)  # type: ignore[arg-type]
    grey = image[:, :, 0].copy()
    for suffix in (".bmp", ".tif", ".pgm"):
        path = tmp_path / f"grey{suffix}"
        assert cv2.imwrite(str(path), grey)
        np.testing.assert_array_equal(read_image(path, colour=True), grey)  # type: ignore[arg-type]


def test_an_image_folder_of_grey_and_colour_images_skips_none(tmp_path: Path) -> None:
    folder = tmp_path / "mixed"
    folder.mkdir()
    image = colour_image(26)
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    for k, pixels in enumerate((image, grey, image)):
        assert cv2.imwrite(str(folder / f"{k:03d}.png"), pixels)
    reader = open_image_folder(folder, fps=10.0)
    frames = list(reader.frames())
    assert reader.counters.image_size_changes == 0
    assert [f.image.ndim for f in frames] == [3, 2, 3]
    np.testing.assert_array_equal(frames[1].image, grey)


def _colour_video(path: Path, images: list[np.ndarray]) -> list[np.ndarray]:
    """Write ``images`` as a Motion-JPEG video; the frames OpenCV reads back from it."""
    fourcc = cv2.VideoWriter_fourcc(*"MJPG")
    writer = cv2.VideoWriter(str(path), fourcc, 10.0, (416, 240), True)
    for image in images:
        writer.write(image)
    writer.release()
    capture = cv2.VideoCapture(str(path))
    read = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        read.append(frame)
    capture.release()
    return read


def test_a_colour_video_gives_its_frames_as_opencv_reads_them(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    expected = _colour_video(path, [colour_image(40 + k) for k in range(3)])
    assert len(expected) == 3 and expected[0].shape == (240, 416, 3)
    with open_video(path) as reader:
        frames = list(reader.frames())
    for frame, image in zip(frames, expected, strict=True):
        np.testing.assert_array_equal(frame.image, image)
    with open_video(path, frontend=WHOLE) as reader:  # cogmap's whole crop: the luma
        grey = list(reader.frames())
    for frame, image in zip(grey, expected, strict=True):
        np.testing.assert_array_equal(frame.image, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))


def test_the_camera_panel_shows_red_green_blue() -> None:
    image = colour_image(50, 24, 40)
    rgb = camera_rgb(image)
    assert rgb.shape == (24, 40, 3) and rgb.flags.c_contiguous
    np.testing.assert_array_equal(rgb[:, :, 0], image[:, :, 2])  # red
    np.testing.assert_array_equal(rgb[:, :, 1], image[:, :, 1])
    np.testing.assert_array_equal(rgb[:, :, 2], image[:, :, 0])  # blue
    grey = image[:, :, 1].copy()
    np.testing.assert_array_equal(camera_rgb(grey), np.dstack([grey] * 3))


def test_the_page_lists_and_opens_videos_and_image_folders(tmp_path: Path) -> None:
    from tests.test_server_support import running_app, wait

    data = tmp_path / "data"
    folder = data / "colour"
    folder.mkdir(parents=True)
    images = [colour_image(60 + k) for k in range(4)]
    for k, image in enumerate(images):
        assert cv2.imwrite(str(folder / f"{k:03d}.png"), image)
    video = _colour_video(data / "clip.avi", images[:3])
    (data / "linked").mkdir()  # an image that is a link: the folder is not listed
    (data / "linked" / "a.png").symlink_to(folder / "000.png")
    assert cv2.imwrite(str(data / "loose.png"), images[0])  # the data folder itself: not listed
    (data / "notes").mkdir()
    (data / "notes" / "readme.md").write_text("no images here")
    options = CameraOptions(fps=10.0)
    read = InputOptions(format="images", camera=options)
    with running_app(folder, input_options=read, data_dirs=[data]) as app:
        wait(app)
        # the last frame, red-green-blue, on the camera panel
        np.testing.assert_array_equal(app.camera_image.image, images[-1][:, :, ::-1])
        assert tuple(app.bag_dropdown.options) == ("clip.avi", "colour")
        assert app.open_bag("clip.avi"), app.open_md.content
        wait(app)
        assert app.replay.format == "video" and app.replay.session.log.frames == 3
        np.testing.assert_array_equal(app.camera_image.image, video[-1][:, :, ::-1])
        # checked again when opened: an image turned into a link is refused
        (folder / "001.png").unlink()
        (folder / "001.png").symlink_to(folder / "000.png")
        assert not app.open_bag("colour")
        assert "not opened: colour is not a folder of images any more" in app.open_md.content
