"""Local view cells: template extraction, shifted matching, new templates, fast == exhaustive."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from cogmap_core.errors import InputFileError
from cogmap_core.frontend import FrontEndConfig, LocalViewCells
from cogmap_core.frontend.config import COGMAP_ARITHMETIC
from cogmap_core.frontend.local_view import VALUE_SCALE

# The 8-bit whole-crop templates (cogmap's former arithmetic, a named setting); the tests of
# OpenRatSLAM's whole-pixel blocks (the default) are at the end.
WHOLE = FrontEndConfig(**COGMAP_ARITHMETIC)

# A reference image 420 px wide with the crop rows 0-140: every template pixel is exactly one
# 7x7 block of the image, so an image built from 7x7 blocks gives a known template.
BLOCK = 7
EXACT = WHOLE.with_changes(
    reference_image_width=420,
    image_crop_x_max=420,
    image_crop_y_max=140,
    camera_hfov_deg=60.0,
)


def strip(seed: int, width: int = 80, height: int = 20, contrast: float = 1.0) -> np.ndarray:
    """A smooth random texture at template resolution (a 'panorama' wider than a view)."""
    rng = np.random.default_rng(seed)
    a = rng.random((height, width))
    a = cv2.GaussianBlur(a, (0, 0), 1.2)
    a = (a - a.min()) / (a.max() - a.min())
    return np.clip(40 + 170 * contrast * a, 0, 255).astype(np.uint8)


def view_image(panorama: np.ndarray, start: int) -> np.ndarray:
    """A 420x240 camera image whose template is ``panorama[:, start:start + 60]``."""
    cells = panorama[:, start : start + 60]
    top = np.kron(cells, np.ones((BLOCK, BLOCK), dtype=np.uint8))  # 140 x 420
    bottom = np.full((100, 420), 17, dtype=np.uint8)  # below the crop: ignored
    return np.vstack([top, bottom])


def test_template_is_the_area_mean_of_the_crop() -> None:
    lv = LocalViewCells(WHOLE)
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur((rng.random((240, 416)) * 255).astype(np.uint8), (0, 0), 2)
    template = lv.make_template(image)
    assert template.shape == (20, 60) and template.dtype == np.uint8
    reference = cv2.resize(image[:150], (60, 20), interpolation=cv2.INTER_AREA)
    assert np.abs(template.astype(int) - reference).max() <= 1
    # The rows below the crop do not matter.
    image2 = image.copy()
    image2[150:] = 0
    assert np.array_equal(lv.make_template(image2), template)


@pytest.mark.parametrize("scale", [2, 4])
def test_reduced_images_give_nearly_the_same_template(scale: int) -> None:
    lv = LocalViewCells(WHOLE)
    rng = np.random.default_rng(2)
    image = cv2.GaussianBlur((rng.random((240, 416)) * 255).astype(np.uint8), (0, 0), 6)
    small = cv2.resize(image, (416 // scale, 240 // scale), interpolation=cv2.INTER_AREA)
    full = lv.make_template(image).astype(int)
    reduced = lv.make_template(small).astype(int)
    assert reduced.shape == (20, 60)
    assert np.abs(full - reduced).mean() < 1.5


def test_exact_block_images_give_the_block_template() -> None:
    lv = LocalViewCells(EXACT)
    pano = strip(3)
    assert np.array_equal(lv.make_template(view_image(pano, 10)), pano[:, 10:70])


def test_bad_images_are_rejected() -> None:
    lv = LocalViewCells(WHOLE)
    with pytest.raises(InputFileError):  # (a colour image has three channels: see below)
        lv.make_template(np.zeros((240, 416, 4), dtype=np.uint8))
    with pytest.raises(InputFileError):
        lv.make_template(np.zeros((240, 416), dtype=np.float32))  # type: ignore[arg-type]
    with pytest.raises(InputFileError):
        lv.make_template(np.zeros((1, 1), dtype=np.uint8))


@pytest.mark.parametrize("k", [-4, -3, -1, 0, 2, 4])
def test_shifted_view_matches_with_the_relative_angle(k: int) -> None:
    lv = LocalViewCells(EXACT)
    pano = strip(4)
    first = lv.observe(view_image(pano, 10))
    assert (first.template_id, first.is_new) == (0, True)
    other = lv.observe(view_image(strip(5), 10))  # an unrelated place
    assert (other.template_id, other.is_new) == (1, True)
    # The camera turned so that the view window moved k template columns to the right.
    match = lv.observe(view_image(pano, 10 + k))
    assert match.template_id == 0 and not match.is_new
    assert match.offset == 4 + k
    assert match.error == 0.0
    # 60 deg over 60 columns: one degree per column; turning right (window to the right) < 0.
    assert match.relative_rad == pytest.approx(-math.radians(k), abs=1e-12)
    assert lv.count == 2


def test_shift_beyond_the_search_range_makes_a_new_template() -> None:
    lv = LocalViewCells(EXACT)
    pano = strip(6)
    lv.observe(view_image(pano, 5))
    result = lv.observe(view_image(pano, 5 + 12))
    assert result.is_new and result.template_id == 1


def test_threshold_is_inclusive_and_exact() -> None:
    lv = LocalViewCells(WHOLE)
    flat = np.full((20, 60), 100, dtype=np.uint8)
    lv.add(flat)
    # The compared window is 52 x 20 = 1040 pixels; the threshold is 0.03 * 1040 * 255 = 7956.
    assert lv.max_sad == 7956
    view = flat.astype(int)
    centre = view[:, 4:56].reshape(-1)
    centre += 7
    centre[:676] += 1  # SAD = 676 * 8 + 364 * 7 = 7956
    view[:, 4:56] = centre.reshape(20, 52)
    at = lv.match(view.astype(np.uint8))
    assert (at.template_id, at.sad) == (0, 7956)
    view[0, 30] += 1
    assert not lv.match(view.astype(np.uint8)).matched
    assert not lv.match_exhaustive(view.astype(np.uint8)).matched


def test_ties_break_by_lowest_template_then_lowest_offset() -> None:
    lv = LocalViewCells(WHOLE)
    flat = np.full((20, 60), 90, dtype=np.uint8)
    pano = strip(7)
    lv.add(pano[:, 0:60])
    lv.add(flat)
    lv.add(flat)
    for search in (lv.match, lv.match_exhaustive):
        result = search(flat)
        assert (result.template_id, result.offset, result.sad) == (1, 0, 0)


def _families(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """Templates in a few families of near-duplicates (shifted, noisy, brightness-changed)."""
    bases = [strip(100 + i, contrast=0.3 + 0.1 * i) for i in range(6)]
    out = []
    for _ in range(count):
        base = bases[rng.integers(len(bases))]
        start = int(rng.integers(0, 20))
        t = base[:, start : start + 60].astype(int)
        t = t + rng.integers(-12, 13) + rng.normal(0, rng.choice([0.0, 1.0, 4.0]), t.shape)
        out.append(np.clip(np.rint(t), 0, 255).astype(np.uint8))
    return out


def test_fast_matcher_equals_exhaustive_search() -> None:
    rng = np.random.default_rng(8)
    lv = LocalViewCells(WHOLE)
    stored = _families(rng, 400)
    for t in stored[:150]:
        lv.add(t)
    lv.add(stored[3])  # an exact duplicate: ties between templates
    for t in stored[150:]:
        lv.add(t)
    assert lv._indexed > 0 and lv.count > lv._indexed  # sorted index and unsorted tail in use
    unrelated = [strip(500 + i, contrast=0.3 + 0.01 * i)[:, :60] for i in range(40)]
    queries = _families(rng, 300) + unrelated + [stored[i] for i in range(0, 400, 37)]
    matched = 0
    for q in queries:
        hint = int(rng.integers(-1, lv.count)) if rng.random() < 0.7 else None
        hint = None if hint == -1 else hint
        fast = lv.match(q, hint)
        slow = lv.match_exhaustive(q)
        assert (fast.template_id, fast.offset, fast.sad) == (
            slow.template_id,
            slow.offset,
            slow.sad,
        )
        matched += fast.matched
        # The pruning really prunes: far fewer exact comparisons than the exhaustive search.
        assert fast.candidates < slow.candidates
    assert 50 < matched <= len(queries) - 30  # both outcomes are exercised


def test_level0_key_follows_the_data_and_stays_exact() -> None:
    """Templates of equal brightness (normalised views): the key is not the window sum."""
    rng = np.random.default_rng(21)

    def normalised(t: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(t * (100.0 / t.mean())), 0, 255).astype(np.uint8)

    stored = [normalised(t.astype(float)) for t in _families(rng, 300)]
    lv = LocalViewCells(WHOLE)
    for t in stored:
        lv.add(t)
    assert lv._indexed > 0
    assert set(lv._signs.tolist()) == {-1.0, 1.0}  # a signed key, not the plain window sum
    keys = lv._keys_all[: lv.count].ravel()
    sums = lv._desc1[: lv.count].reshape(-1, lv._k1).sum(axis=1)
    assert keys.std() > 2 * sums.std()  # it spreads the pairs wider than the window sum
    queries = [normalised(t.astype(float)) for t in _families(rng, 120)]
    for q in queries + stored[::29]:
        fast, slow = lv.match(q), lv.match_exhaustive(q)
        assert (fast.template_id, fast.offset, fast.sad) == (
            slow.template_id,
            slow.offset,
            slow.sad,
        )


def test_observe_reports_the_error_of_a_match() -> None:
    lv = LocalViewCells(EXACT)
    pano = strip(9)
    lv.observe(view_image(pano, 10))
    noisy = view_image(pano, 10).astype(int)
    noisy[:140] += 3
    result = lv.observe(np.clip(noisy, 0, 255).astype(np.uint8))
    assert result.template_id == 0 and not result.is_new
    assert result.error == pytest.approx(3 / 255)


def test_global_normalisation_scales_to_the_target_mean() -> None:
    lv = LocalViewCells(EXACT.with_changes(vt_normalisation=0.4))
    image = np.full((240, 420), 50, dtype=np.uint8)
    assert np.all(lv.make_template(image) == 102)  # 0.4 * 255


def test_patch_normalisation_is_local_contrast() -> None:
    lv = LocalViewCells(EXACT.with_changes(vt_patch_normalise=2))
    flat = np.full((240, 420), 90, dtype=np.uint8)
    assert np.all(lv.make_template(flat) == 128)  # no contrast anywhere: 0.5
    # A vertical edge: dark left half, bright right half, at any overall brightness.
    for low, high in ((20, 60), (120, 240)):
        pano = np.full((20, 80), low, dtype=np.uint8)
        pano[:, 40:] = high
        t = lv.make_template(view_image(pano, 10)).astype(int)
        assert np.all(t[:, :28] == 128) and np.all(t[:, 32:] == 128)  # far from the edge
        # Next to it, (z + 3) / 6 of the 5x5 patch: e.g. column 29 sees 3 dark and 2 bright
        # columns, mean 0.4, std 0.49: z = -0.816 -> 0.364 -> 93.
        assert np.all(t[:, 28:32] == [106, 93, 162, 149])
        if low == 20:
            first = t
        else:
            assert np.array_equal(t, first)  # independent of brightness and contrast


# ----------------------------------------------------------------- OpenRatSLAM's arithmetic
def test_template_is_openratslams_whole_pixel_block_means() -> None:
    """iRat geometry: 416/60 -> 6 by 150/20 -> 7 pixel blocks over columns 0-359, rows 0-139."""
    lv = LocalViewCells(FrontEndConfig())
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (240, 416), dtype=np.uint8)
    template = lv.make_template(image)
    assert template.shape == (20, 60) and template.dtype == np.int32
    sums = image[:140, :360].astype(np.int64).reshape(20, 7, 60, 6).sum(axis=(1, 3))
    assert np.array_equal(template, np.rint(sums / 255.0 / 42 * VALUE_SCALE).astype(np.int32))
    changed = image.copy()
    changed[140:, :] = 0  # rows past the last whole block
    changed[:, 360:] = 255  # columns past it
    assert np.array_equal(lv.make_template(changed), template)


def test_block_normalisation_is_openratslams() -> None:
    lv = LocalViewCells(FrontEndConfig(vt_normalisation=0.4))
    image = np.full((240, 416), 50, dtype=np.uint8)
    image[:7, :6] = 200  # one brighter block
    view = np.full((20, 60), 50 / 255.0)
    view[0, 0] = 200 / 255.0
    expected = np.clip(view * 0.4 / (view.sum() / view.size), 0.0, 1.0)
    assert np.array_equal(lv.make_template(image), np.rint(expected * VALUE_SCALE))


def test_block_threshold_is_inclusive_at_full_precision() -> None:
    lv = LocalViewCells(FrontEndConfig(vt_mean_skip=0))
    flat = np.full((20, 60), 400_000, dtype=np.int32)
    lv.add(flat)
    # 0.03 * 1040 pixels * 2^20 = 32715571.2: the largest SAD that matches is 32715571.
    assert lv.max_sad == 32_715_571
    view = flat.copy()
    view[:, 4:56] += 31_457  # SAD 32715280
    view[0, 4] += 291  # SAD 32715571
    assert lv.match(view).sad == 32_715_571
    view[0, 5] += 1
    assert not lv.match(view).matched and not lv.match_exhaustive(view).matched


def test_mean_skip_leaves_out_templates_of_another_mean() -> None:
    """OpenRatSLAM skips a template whose mean is more than threshold + 0.005 off, even when
    the compared columns match: the edge columns count in the mean, not in the comparison."""
    q = VALUE_SCALE // 100
    template = np.full((20, 60), 50 * q, dtype=np.int32)
    view = template.copy()
    view[:, :4] += 30 * q  # 8 of 60 columns 0.3 brighter: mean 0.04 higher
    view[:, 56:] += 30 * q
    for skip, matched in ((1, False), (0, True)):
        lv = LocalViewCells(FrontEndConfig(vt_mean_skip=skip))
        lv.add(template)
        assert lv.match(view).matched is matched
        assert lv.match(view, hint=0).matched is matched
        assert lv.match_exhaustive(view).matched is matched
    view[:, 56:] -= 30 * q  # mean 0.02 higher: within 0.035
    lv = LocalViewCells(FrontEndConfig())
    lv.add(template)
    assert lv.match(view).sad == 0


def test_block_fast_matcher_equals_exhaustive_search() -> None:
    rng = np.random.default_rng(9)
    lv = LocalViewCells(FrontEndConfig())
    scale = VALUE_SCALE // 255

    def fixed(t: np.ndarray) -> np.ndarray:
        noise = rng.integers(0, scale, t.shape)
        return (t.astype(np.int64) * scale + noise).astype(np.int32)

    stored = [fixed(t) for t in _families(rng, 300)]
    for t in stored:
        lv.add(t)
    assert lv._indexed > 0 and lv._desc1.dtype == np.float64  # sums past 2^24: exact in float64
    matched = 0
    unrelated = [fixed(strip(600 + i, contrast=0.3 + 0.01 * i)[:, :60]) for i in range(30)]
    queries = [fixed(t) for t in _families(rng, 150)] + stored[::23] + unrelated
    for q in queries:
        fast, slow = lv.match(q, int(rng.integers(lv.count))), lv.match_exhaustive(q)
        assert (fast.template_id, fast.offset, fast.sad) == (
            slow.template_id,
            slow.offset,
            slow.sad,
        )
        matched += fast.matched
    assert 20 < matched <= len(queries) - 20  # both outcomes are exercised


def test_block_templates_need_a_whole_pixel_per_template_pixel() -> None:
    lv = LocalViewCells(FrontEndConfig())
    with pytest.raises(InputFileError, match="too small"):
        lv.make_template(np.zeros((30, 52), dtype=np.uint8))  # a JPEG decoded at 1/8
    with pytest.raises(ValueError, match="int32"):
        lv.add(np.zeros((20, 60), dtype=np.uint8))
    with pytest.raises(ValueError, match="values"):
        lv.add(np.full((20, 60), VALUE_SCALE + 1, dtype=np.int32))
