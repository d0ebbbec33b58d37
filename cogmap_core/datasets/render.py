"""A vectorised ray caster that renders the iRat's camera view of a maze.

The maze walls are the boundary faces of the layout's wall cells, merged into straight segments.
Every image column casts one ray against all faces at once (numpy), giving the hit face, the
texture coordinate along it and the depth; every pixel row then looks up the wall texture, the
floor under the maze or, above the walls, the laboratory's ceiling and walls.

Appearance (all procedural, fixed for a given layout):

- walls: a few shared base materials (painted board, wood, brick, tiles) so that plain corridors
  look alike (perceptual aliasing), with landmark decals (stripes, checkers, discs, triangles,
  blobs) on many faces so that places are recognisable; some decal designs occur twice;
- static lighting from a few ceiling lamps and a window side, baked into the textures; a
  darker skirting and a lighter top edge on the walls; floor darkening near walls;
- per frame: global light level (given by the caller), distance fall-off, vignetting, optical
  blur, a small gain flicker and Gaussian sensor noise, then 8-bit quantisation.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from cogmap_core.datasets.layout import Layout

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]

WALL_HEIGHT = 0.25  # m
CEILING_HEIGHT = 2.2  # m, the laboratory ceiling
ROOM_MARGIN = 2.5  # m, laboratory walls this far around the maze
_WALL_TEX_H = 64  # texels over the wall height
_WALL_TEX_DENSITY = 256.0  # texels per metre along a wall
_FLOOR_TEX_DENSITY = 128.0
_ROOM_TEX_DENSITY = 32.0
_NOISE_BANK = 1024
_EXPOSURE = 280.0  # grey levels per unit radiance: walls average about 110 at light level 1


@dataclass(frozen=True)
class CameraModel:
    """A forward-looking pinhole camera on the robot.

    Attributes:
        width, height: image size in pixels (the iRat's is 416 x 240).
        hfov_deg: horizontal field of view.
        mount_height: camera height above the floor (m).
        horizon_row: image row of the horizon (the camera looks level).

    """

    width: int = 416
    height: int = 240
    hfov_deg: float = 70.0
    mount_height: float = 0.05
    horizon_row: float = 120.0

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2.0)


@dataclass(frozen=True)
class WallFaces:
    """Straight wall faces, each seen from the free side.

    ``p0`` is the left end as seen by a viewer facing the wall; the texture coordinate runs from
    ``p0`` (0) to ``p1`` (``length``). ``normal`` points into the free space.
    """

    p0: FloatArray
    p1: FloatArray
    normal: FloatArray

    @property
    def length(self) -> FloatArray:
        """Face lengths (m)."""
        d = self.p1 - self.p0
        return np.hypot(d[:, 0], d[:, 1])

    def __len__(self) -> int:
        return int(self.p0.shape[0])


def extract_faces(walls: NDArray[np.bool_], cell: float) -> WallFaces:
    """Boundary faces between wall and free cells, merged into maximal straight runs.

    The outside of the grid counts as wall, so the free space is closed.
    """
    padded = np.pad(walls, 1, constant_values=True)
    rows = padded.shape[0] - 2  # rows of the real grid; padded row i is grid row i - 1
    p0s: list[tuple[float, float]] = []
    p1s: list[tuple[float, float]] = []
    normals: list[tuple[float, float]] = []

    def y_of(grid_row_edge: float) -> float:
        return (rows - grid_row_edge) * cell

    # (dr, dc): the free neighbour of a wall cell lies at (r + dr, c + dc); the normal points to it.
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        # (the padded border is all wall, so the wrap-around of roll never makes a face)
        face = padded & ~np.roll(np.roll(padded, -dr, axis=0), -dc, axis=1)
        if dr:  # horizontal faces: runs along columns
            for r in range(padded.shape[0]):
                for start, stop in _runs(face[r]):
                    gr = r - 1
                    edge_y = y_of(gr) if dr == -1 else y_of(gr + 1)
                    xa, xb = (start - 1) * cell, (stop - 1) * cell
                    if dr == -1:  # free to the north, viewer looks south: left is east
                        p0s.append((xb, edge_y))
                        p1s.append((xa, edge_y))
                        normals.append((0.0, 1.0))
                    else:  # free to the south, viewer looks north: left is west
                        p0s.append((xa, edge_y))
                        p1s.append((xb, edge_y))
                        normals.append((0.0, -1.0))
        else:  # vertical faces: runs along rows
            for c in range(padded.shape[1]):
                for start, stop in _runs(face[:, c]):
                    gc = c - 1
                    edge_x = gc * cell if dc == -1 else (gc + 1) * cell
                    ya, yb = y_of(start - 1), y_of(stop - 1)  # ya north end, yb south end
                    if dc == -1:  # free to the west, viewer looks east: left is north
                        p0s.append((edge_x, ya))
                        p1s.append((edge_x, yb))
                        normals.append((-1.0, 0.0))
                    else:  # free to the east, viewer looks west: left is south
                        p0s.append((edge_x, yb))
                        p1s.append((edge_x, ya))
                        normals.append((1.0, 0.0))
    return WallFaces(np.array(p0s), np.array(p1s), np.array(normals))


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in a 1-D boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def layout_seed(layout: Layout) -> int:
    """A stable seed for a layout's appearance (from its walls and waypoints)."""
    data = layout.walls.tobytes() + str(layout.walls.shape).encode()
    return zlib.crc32(data) ^ int(round(layout.cell * 1e6))


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> FloatArray:
    """Zero-mean, unit-std low-pass noise."""
    field = ndimage.gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap")
    return (field - field.mean()) / (field.std() + 1e-12)


class MazeRenderer:
    """Renders grayscale camera images of a layout from robot poses."""

    def __init__(self, layout: Layout, camera: CameraModel | None = None) -> None:
        """Build faces and textures (deterministic for the layout)."""
        self.layout = layout
        self.camera = camera or CameraModel()
        self.faces = extract_faces(layout.walls, layout.cell)
        seed = layout_seed(layout)
        rng = np.random.default_rng(seed)
        w, h = layout.size_m
        self._lamps = np.column_stack(
            [rng.uniform(0.15 * w, 0.85 * w, 4), rng.uniform(0.15 * h, 0.85 * h, 4)]
        )
        self._lamp_power = rng.uniform(0.25, 0.45, 4)
        angle = rng.uniform(0, 2 * np.pi)
        self._window_dir = np.array([math.cos(angle), math.sin(angle)])
        self._build_wall_atlas(rng)
        self._build_floor(rng)
        self._build_room(rng)
        self._build_camera_tables()
        noise_rng = np.random.default_rng(seed ^ 0x5EED)
        self._noise = noise_rng.standard_normal((_NOISE_BANK, _NOISE_BANK)).astype(np.float32)

    # ----------------------------------------------------------------------------- textures
    def _static_light(self, xy: FloatArray) -> FloatArray:
        """Lamp light at world points (ambient + Gaussian pools under the lamps)."""
        d2 = ((xy[:, None, :] - self._lamps[None, :, :]) ** 2).sum(axis=2)
        return 0.7 + (self._lamp_power[None, :] * np.exp(-d2 / (2 * 0.9**2))).sum(axis=1)

    def _build_wall_atlas(self, rng: np.random.Generator) -> None:
        faces = self.faces
        lengths = faces.length
        widths = np.maximum(1, np.ceil(lengths * _WALL_TEX_DENSITY).astype(np.int64))
        offsets = np.concatenate([[0], np.cumsum(widths)[:-1]])
        total = int(widths.sum())
        atlas = np.empty((_WALL_TEX_H, total), dtype=np.float32)
        materials = [_material(rng, k) for k in range(4)]
        designs: list[F32] = []
        v = (np.arange(_WALL_TEX_H) + 0.5) / _WALL_TEX_H  # 0 = top, 1 = bottom
        height_light = (1.0 - 0.15 * v)[:, None]
        for i in range(len(faces)):
            n = int(widths[i])
            material = materials[int(rng.integers(len(materials)))]
            start = int(rng.integers(material.shape[1]))
            cols = (start + np.arange(n)) % material.shape[1]
            # each face has its own shade of the shared material
            strip = material[:, cols] * float(rng.uniform(0.85, 1.15))
            # landmark decals: at least one on every face that can hold one; faces up to half a
            # metre (corridor ends, corners) get designs of their own, longer ones may repeat one
            n_decals = max(1, int(rng.poisson(lengths[i] / 0.45))) if lengths[i] > 0.2 else 0
            for _ in range(n_decals):
                if designs and lengths[i] > 0.5 and rng.random() < 0.1:
                    decal = designs[int(rng.integers(len(designs)))]  # a look-alike place
                else:
                    decal = _decal(rng)
                    designs.append(decal)
                dh, dw = decal.shape
                if dw >= n - 2:  # a narrow face shows part of the design
                    if n < 12:
                        continue
                    decal = decal[:, : n - 4]
                    dw = n - 4
                c0 = int(rng.integers(1, n - dw - 1))
                r0 = int(rng.integers(4, max(5, _WALL_TEX_H - dh - 6)))
                r1 = min(_WALL_TEX_H, r0 + dh)
                alpha = decal[: r1 - r0]
                tone = float(rng.choice([0.08, 0.15, 0.9, 0.97]))
                region = strip[r0:r1, c0 : c0 + dw]
                strip[r0:r1, c0 : c0 + dw] = region * (1.0 - alpha) + tone * alpha
            # skirting and top edge
            strip[-3:, :] = 0.22
            strip[:2, :] = 0.85
            # baked lighting along the face
            t = (np.arange(n) + 0.5) / _WALL_TEX_DENSITY
            direction = (faces.p1[i] - faces.p0[i]) / max(lengths[i], 1e-9)
            pts = faces.p0[i][None, :] + t[:, None] * direction[None, :]
            light = self._static_light(pts)
            facing = 0.82 + 0.18 * float(faces.normal[i] @ self._window_dir)
            strip = strip * (light[None, :] * facing) * height_light
            atlas[:, offsets[i] : offsets[i] + n] = strip
        self._atlas = cv2.GaussianBlur(atlas, (0, 0), 0.7).ravel()
        self._atlas_width = total
        self._face_offset = offsets
        self._face_width = widths

    def _build_floor(self, rng: np.random.Generator) -> None:
        layout = self.layout
        w, h = layout.size_m
        nx = int(math.ceil(w * _FLOOR_TEX_DENSITY)) + 2
        ny = int(math.ceil(h * _FLOOR_TEX_DENSITY)) + 2
        base = 0.42 + 0.05 * _smooth_noise(rng, (ny, nx), 12.0)
        base += 0.03 * _smooth_noise(rng, (ny, nx), 1.5)
        ys = (ny - 1 - np.arange(ny) + 0.5) / _FLOOR_TEX_DENSITY  # texel row 0 = north
        xs = (np.arange(nx) + 0.5) / _FLOOR_TEX_DENSITY
        gx, gy = np.meshgrid(xs, ys)
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        light = self._static_light(pts).reshape(ny, nx)
        # darker near walls (ambient occlusion)
        rr = np.clip((layout.rows - gy / layout.cell).astype(np.int64), 0, layout.rows - 1)
        cc = np.clip((gx / layout.cell).astype(np.int64), 0, layout.cols - 1)
        free_fine = ~layout.walls[rr, cc]
        dist = ndimage.distance_transform_edt(free_fine) / _FLOOR_TEX_DENSITY
        occlusion = 1.0 - 0.35 * np.exp(-dist / 0.03)
        floor = (base * light * occlusion).astype(np.float32)
        self._floor = cv2.GaussianBlur(floor, (0, 0), 0.8)
        self._floor_flat = self._floor.ravel()
        self._floor_shape = (ny, nx)

    def _build_room(self, rng: np.random.Generator) -> None:
        """The laboratory: a ceiling with light panels and four walls around the maze."""
        w, h = self.layout.size_m
        x0, y0 = -ROOM_MARGIN, -ROOM_MARGIN
        x1, y1 = w + ROOM_MARGIN, h + ROOM_MARGIN
        self._room = (x0, y0, x1, y1)
        nx = int((x1 - x0) * _ROOM_TEX_DENSITY)
        ny = int((y1 - y0) * _ROOM_TEX_DENSITY)
        ceil = 0.5 + 0.03 * _smooth_noise(rng, (ny, nx), 6.0)
        # rows of fluorescent panels
        px, py = 1.4, 1.1
        gx = (np.arange(nx) + 0.5) / _ROOM_TEX_DENSITY
        gy = (np.arange(ny) + 0.5) / _ROOM_TEX_DENSITY
        in_x = (gx % px) < 0.35
        in_y = (gy % py) < 0.7
        ceil[np.ix_(in_y, in_x)] = 1.9
        for _ in range(6):  # vents and beams break the regularity
            cx, cy = int(rng.integers(nx)), int(rng.integers(ny))
            ceil[cy : cy + int(rng.integers(4, 12)), cx : cx + int(rng.integers(4, 40))] = 0.2
        self._ceiling = ceil.astype(np.float32).ravel()
        self._ceiling_shape = (ny, nx)
        # four walls: texture rows over the ceiling height, columns along the perimeter
        per = int(2 * ((x1 - x0) + (y1 - y0)) * _ROOM_TEX_DENSITY)
        rh = int(CEILING_HEIGHT * _ROOM_TEX_DENSITY)
        wall = 0.62 + 0.04 * _smooth_noise(rng, (rh, per), 8.0)
        wall[-3:, :] = 0.3
        for _ in range(14):  # windows, doors, cupboards, posters
            kind = int(rng.integers(4))
            c0 = int(rng.integers(per - 60))
            width = int(rng.integers(15, 60))
            if kind == 0:  # window
                r0, r1, tone = int(0.3 * rh), int(0.8 * rh), 1.8
            elif kind == 1:  # door
                r0, r1, tone = int(0.1 * rh), rh - 2, 0.25
            elif kind == 2:  # cupboard
                r0, r1, tone = int(0.55 * rh), rh - 2, 0.35
            else:  # poster
                r0 = int(rng.integers(int(0.2 * rh), int(0.5 * rh)))
                r1, tone = r0 + int(rng.integers(8, 20)), float(rng.uniform(0.1, 0.95))
            wall[r0:r1, c0 : c0 + width] = tone
        self._room_wall = wall.astype(np.float32).ravel()
        self._room_wall_shape = (rh, per)

    def _build_camera_tables(self) -> None:
        cam = self.camera
        f = cam.focal
        cols = np.arange(cam.width) + 0.5
        self._lateral = ((0.5 * cam.width - cols) / f).astype(np.float64)  # left positive
        self._col_angle = np.arctan(self._lateral)
        self._cos_col = np.cos(self._col_angle)
        rows = np.arange(cam.height) + 0.5
        self._row_off = (rows - cam.horizon_row).astype(np.float32)  # > 0 below the horizon
        yy, xx = np.mgrid[0 : cam.height, 0 : cam.width]
        r2 = ((xx - cam.width / 2) / (cam.width / 2)) ** 2 + (
            (yy - cam.height / 2) / (cam.width / 2)
        ) ** 2
        self._vignette = (1.0 - 0.28 * r2).astype(np.float32)
        self._split = int(math.ceil(cam.horizon_row))

    # ------------------------------------------------------------------------------ casting
    def cast(
        self, x: float, y: float, theta: float
    ) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:
        """Cast one ray per image column.

        Returns:
            ``(depth, face, u)``: perpendicular depth (m), hit face index (-1: none) and the
            distance along the face from its ``p0`` (m), one value per column.

        """
        x, y, theta = float(x), float(y), float(theta)
        ang = theta + self._col_angle
        dx, dy = np.cos(ang), np.sin(ang)
        faces = self.faces
        e = faces.p1 - faces.p0
        wx = faces.p0[:, 0] - x
        wy = faces.p0[:, 1] - y
        # only faces turned towards the camera position can be hit
        facing = (faces.normal[:, 0] * -wx + faces.normal[:, 1] * -wy) > 0
        ex, ey, wx, wy = e[facing, 0], e[facing, 1], wx[facing], wy[facing]
        idx = np.flatnonzero(facing)
        den = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / den
            t = (wx * ey - wy * ex)[None, :] * inv
            s = (wx[None, :] * dy[:, None] - wy[None, :] * dx[:, None]) * inv
        ok = (den < 0) & (t > 1e-6) & (s >= -1e-9) & (s <= 1.0 + 1e-9)
        t = np.where(ok, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(t.shape[0])
        dist = t[rows, best]
        hit = np.isfinite(dist)
        face = np.where(hit, idx[best], -1) if idx.size else np.full(t.shape[0], -1)
        s_best = s[rows, best] if idx.size else np.zeros(t.shape[0])
        lengths = faces.length
        u = np.where(hit, np.clip(s_best, 0.0, 1.0) * lengths[np.maximum(face, 0)], 0.0)
        depth = np.where(hit, dist * self._cos_col, 1e3)
        return depth, face, u

    def _room_depth(self, x: float, y: float, theta: float) -> tuple[FloatArray, FloatArray]:
        """Perpendicular depth to the laboratory walls and the perimeter texture coordinate."""
        x0, y0, x1, y1 = self._room
        ang = theta + self._col_angle
        dx, dy = np.cos(ang), np.sin(ang)
        with np.errstate(divide="ignore"):
            tx = np.where(dx > 0, (x1 - x) / dx, (x0 - x) / dx)
            ty = np.where(dy > 0, (y1 - y) / dy, (y0 - y) / dy)
        t = np.minimum(np.abs(tx), np.abs(ty))
        hx, hy = x + t * dx, y + t * dy
        wx, wy = x1 - x0, y1 - y0
        # perimeter coordinate, counter-clockwise from (x0, y0)
        per = np.where(
            np.abs(hy - y0) < 1e-6,
            hx - x0,
            np.where(
                np.abs(hx - x1) < 1e-6,
                wx + (hy - y0),
                np.where(np.abs(hy - y1) < 1e-6, wx + wy + (x1 - hx), 2 * wx + wy + (y1 - hy)),
            ),
        )
        return t * self._cos_col, per

    # ----------------------------------------------------------------------------- drawing
    def render_float(self, x: float, y: float, theta: float) -> F32:
        """Noise-free image radiance (about 0..1, brighter lamps exceed 1), ``float32``."""
        x, y, theta = float(x), float(y), float(theta)  # same result for numpy scalars
        cam = self.camera
        f = np.float32(cam.focal)
        hc = np.float32(cam.mount_height)
        depth, face, u = self.cast(x, y, theta)
        room_depth, room_u = self._room_depth(x, y, theta)
        c, s = math.cos(theta), math.sin(theta)
        lat = self._lateral
        dirx = (c - lat * s).astype(np.float32)  # ray direction per unit forward depth
        diry = (s + lat * c).astype(np.float32)

        depth32 = depth.astype(np.float32)
        z = hc - self._row_off[:, None] * (depth32[None, :] / f)  # height where the ray hits
        wall = (z >= 0) & (z < WALL_HEIGHT)
        tex_v = np.clip(
            ((WALL_HEIGHT - z) * (_WALL_TEX_H / WALL_HEIGHT)).astype(np.int32), 0, _WALL_TEX_H - 1
        )
        face_c = np.maximum(face, 0)
        tex_u = (
            np.minimum((u * _WALL_TEX_DENSITY).astype(np.int64), self._face_width[face_c] - 1)
            + self._face_offset[face_c]
        )
        img = self._atlas[tex_v * self._atlas_width + tex_u[None, :].astype(np.int32)]
        fall = (1.0 / (1.0 + 0.12 * depth32)).astype(np.float32)
        img *= fall[None, :]

        split = self._split
        # floor (below the horizon, below the wall)
        lower = self._row_off[split:]
        fd = (f * hc / lower)[:, None]  # forward depth per row
        fx = x + fd * dirx[None, :]
        fy = y + fd * diry[None, :]
        ny, nx = self._floor_shape
        ix = np.clip((fx * _FLOOR_TEX_DENSITY).astype(np.int32), 0, nx - 1)
        iy = np.clip((ny - 1) - (fy * _FLOOR_TEX_DENSITY).astype(np.int32), 0, ny - 1)
        floor = self._floor_flat[iy * nx + ix] / (1.0 + 0.12 * fd)
        lower_img = img[split:]
        np.copyto(lower_img, floor, where=~wall[split:])

        # above the walls: laboratory ceiling or walls
        upper = -self._row_off[:split]  # > 0 above the horizon
        up = upper[:, None]
        cd = ((CEILING_HEIGHT - hc) * f / up).astype(np.float32)  # forward depth to the ceiling
        rd = room_depth.astype(np.float32)[None, :]
        see_ceiling = cd < rd
        x0, y0, _, _ = self._room
        cny, cnx = self._ceiling_shape
        cx = np.clip(
            ((x - x0 + cd * dirx[None, :]) * _ROOM_TEX_DENSITY).astype(np.int32), 0, cnx - 1
        )
        cy = np.clip(
            ((y - y0 + cd * diry[None, :]) * _ROOM_TEX_DENSITY).astype(np.int32), 0, cny - 1
        )
        ceiling = self._ceiling[cy * cnx + cx]
        rh, per = self._room_wall_shape
        rz = hc + up * rd / f  # height on the room wall
        rv = np.clip(((CEILING_HEIGHT - rz) * _ROOM_TEX_DENSITY).astype(np.int32), 0, rh - 1)
        ru = np.clip((room_u * _ROOM_TEX_DENSITY).astype(np.int32), 0, per - 1)
        room = self._room_wall[rv * per + ru[None, :]]
        above = np.where(see_ceiling, ceiling, room) * np.float32(0.8)
        upper_img = img[:split]
        np.copyto(upper_img, above, where=~wall[:split])
        return img

    def render(
        self,
        x: float,
        y: float,
        theta: float,
        light: float = 1.0,
        rng: np.random.Generator | None = None,
        noise_sigma: float = 3.0,
    ) -> NDArray[np.uint8]:
        """Camera image (``uint8``, ``height x width``) at pose ``(x, y, theta)``.

        Args:
            x: camera position east (m).
            y: camera position north (m).
            theta: heading (rad, counter-clockwise from east).
            light: global light level (1 = nominal).
            rng: source of sensor noise and gain flicker; ``None`` renders without noise.
            noise_sigma: standard deviation of the sensor noise in grey levels.

        """
        img = self.render_float(x, y, theta)
        gain = np.float32(_EXPOSURE * light)
        if rng is not None:
            gain *= np.float32(1.0 + 0.02 * rng.standard_normal())
        img *= self._vignette
        img *= gain
        img = cv2.GaussianBlur(img, (3, 3), 0.6)
        if rng is not None and noise_sigma > 0:
            h, w = img.shape
            r0 = int(rng.integers(_NOISE_BANK - h))
            c0 = int(rng.integers(_NOISE_BANK - w))
            img += np.float32(noise_sigma) * self._noise[r0 : r0 + h, c0 : c0 + w]
        np.clip(img, 0.0, 255.0, out=img)
        return (img + np.float32(0.5)).astype(np.uint8)


def encode_jpeg(image: NDArray[np.uint8], quality: int = 80) -> bytes:
    """JPEG bytes of a grayscale image."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 images
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def _material(rng: np.random.Generator, kind: int) -> F32:
    """A tileable wall material, ``_WALL_TEX_H`` rows by about one metre of columns."""
    n = int(_WALL_TEX_DENSITY)
    h = _WALL_TEX_H
    if kind == 0:  # painted boards with seams
        tex = 0.62 + 0.035 * _smooth_noise(rng, (h, n), 6.0)
        seam = int(0.3 * _WALL_TEX_DENSITY)
        tex[:, (np.arange(n) % seam) < 2] = 0.45
    elif kind == 1:  # wood grain
        grain = ndimage.gaussian_filter(rng.standard_normal((h, n)), (0.8, 14.0), mode="wrap")
        tex = 0.5 + 0.6 * grain + 0.03 * np.sin(np.arange(h) * 0.9)[:, None]
    elif kind == 2:  # brick
        tex = np.empty((h, n))
        brick_h, brick_w = 12, 32
        tones = rng.uniform(0.38, 0.52, (h // brick_h + 1, n // brick_w + 2))
        for r in range(h):
            br = r // brick_h
            shift = (brick_w // 2) * (br % 2)
            bc = (np.arange(n) + shift) // brick_w
            tex[r] = tones[br, bc]
            if r % brick_h == 0:
                tex[r] = 0.72
        tex[:, ((np.arange(n) + 0) % brick_w) == 0] = 0.72
    else:  # tiles
        tex = 0.58 + 0.02 * _smooth_noise(rng, (h, n), 3.0)
        tex[(np.arange(h) % 20) < 1, :] = 0.4
        tex[:, (np.arange(n) % 20) < 1] = 0.4
    return tex.astype(np.float32)


def _decal(rng: np.random.Generator) -> F32:
    """A landmark's coverage mask (0..1), at most the wall height tall."""
    h = int(rng.integers(20, 46))
    w = int(rng.integers(30, 80))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = (xx + 0.5) / w, (yy + 0.5) / h
    kind = int(rng.integers(7))
    if kind == 0:  # vertical stripes
        period = rng.uniform(0.15, 0.4)
        mask = ((u / period) % 1.0) < 0.5
    elif kind == 1:  # horizontal bands
        period = rng.uniform(0.25, 0.5)
        mask = ((v / period + rng.uniform()) % 1.0) < 0.5
    elif kind == 2:  # checkerboard
        n = int(rng.integers(2, 5))
        mask = ((np.floor(u * n) + np.floor(v * n * h / w * 1.0 + 0.5)) % 2) < 1
    elif kind == 3:  # disc
        mask = (u - 0.5) ** 2 * (w / h) ** 2 + (v - 0.5) ** 2 < 0.2
    elif kind == 4:  # ring
        r2 = (u - 0.5) ** 2 * (w / h) ** 2 + (v - 0.5) ** 2
        mask = (r2 < 0.22) & (r2 > 0.08)
    elif kind == 5:  # triangle
        mask = np.abs(u - 0.5) < 0.5 * v
    else:  # blob
        mask = _smooth_noise(rng, (h, w), 4.0) > 0.2
    return mask.astype(np.float32)
