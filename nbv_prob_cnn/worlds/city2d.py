"""Procedural 2D city maps (docs/method.md#data-sets): a stand-in for the Inria Aerial Image Labeling building
masks (5000² px at 0.3 m, downsampled to 1250² at 1.2 m), which cannot be downloaded here.

A map (1250×1250 cells of :data:`CELL_M` metres, 1 = building) is built as follows:

* The map is split into 1-5 *districts* (Voronoi cells of random sites), separated by avenues.
* Each district has a *style* (downtown, residential, suburb, industrial: block size, street
  width, lot size, setbacks, build density, building shapes) and a street-grid orientation
  (axis-aligned or rotated).
* Its street grid has irregular block sizes and occasional wide avenues; each block is a park,
  a perimeter block (a ring of buildings around a courtyard, downtown) or a set of lots along
  its two long sides, each lot holding (with the style's density) a rectangle, an L, a U or a
  courtyard building, made of axis-aligned rectangles in the block frame.
* Optionally a river/highway crosses the map as an empty band.

Buildings are rasterized on cell centres (a cell is occupied when its centre is inside a
rectangle). Everything is drawn from ``numpy.random.default_rng(seed)``: the same seed gives
the same map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.datasets import DATASET_SPECS

MAP_SIZE: int = (DATASET_SPECS["2d"].map_shape or (0,))[0]
CELL_M: float = DATASET_SPECS["2d"].resolution_m


@dataclass(frozen=True)
class Style:
    """Parameters of a district style (lengths in metres, ranges are uniform draws)."""

    name: str
    block_m: tuple[float, float]  # block edge length
    street_m: tuple[float, float]  # street width
    lot_m: tuple[float, float]  # lot frontage
    depth_m: tuple[float, float]  # building depth (perpendicular to the street)
    setback_m: tuple[float, float]  # distance building - street
    side_gap_m: tuple[float, float]  # gap between neighbouring buildings
    fill: float  # probability that a lot is built
    perimeter: float  # probability that a block is a perimeter block (ring around a courtyard)
    park: float  # probability that a block is a park (empty)
    shapes: tuple[float, float, float, float]  # weights of rectangle, L, U, courtyard
    deep: float  # probability that a building takes the whole depth of its lot


# fmt: off
STYLES: tuple[Style, ...] = tuple(Style(*row) for row in (
    # name, block_m, street_m, lot_m, depth_m, setback_m, side_gap_m, fill, perimeter, park, shapes, deep
    ("downtown", (60, 130), (14, 24), (14, 32), (14, 24), (0, 1.5), (0, 1.5), 0.92, 0.55, 0.04,
     (0.45, 0.25, 0.1, 0.2), 0.5),
    ("residential", (50, 120), (10, 16), (12, 24), (10, 18), (2, 6), (2, 6), 0.85, 0.1, 0.05,
     (0.6, 0.3, 0.1, 0.0), 0.1),
    ("suburb", (45, 110), (8, 12), (14, 24), (10, 16), (3, 7), (3, 7), 0.8, 0.0, 0.05,
     (0.7, 0.3, 0.0, 0.0), 0.0),
    ("industrial", (110, 240), (15, 26), (40, 100), (25, 80), (4, 12), (6, 18), 0.75, 0.0, 0.1,
     (0.8, 0.15, 0.05, 0.0), 0.3),
))
# fmt: on
STYLE_WEIGHTS: tuple[float, ...] = (0.3, 0.35, 0.2, 0.15)

# A rectangle: centre (u, v) and half sizes (a, b) along u and v, in a district frame, metres.
Rect = tuple[float, float, float, float]


def _building(rng: np.random.Generator, style: Style, w: float, d: float) -> list[tuple[float, float, float, float]]:
    """Boxes ``(s0, t0, s1, t1)`` of one building filling ``[0, w] × [0, d]`` (s along the street,
    t away from it, the street at t = 0)."""
    shape = int(rng.choice(4, p=np.asarray(style.shapes) / sum(style.shapes)))
    if shape == 0 or w < 12 or d < 12:
        return [(0, 0, w, d)]
    if shape == 1:  # L: a wing along the street and one along a side
        t = d * rng.uniform(0.35, 0.6)
        s = w * rng.uniform(0.35, 0.6)
        return [(0, 0, w, t), (0, 0, s, d)] if rng.random() < 0.5 else [(0, 0, w, t), (w - s, 0, w, d)]
    if shape == 2:  # U, open away from the street
        t = d * rng.uniform(0.3, 0.5)
        s = w * rng.uniform(0.2, 0.35)
        return [(0, 0, w, t), (0, 0, s, d), (w - s, 0, w, d)]
    t = min(rng.uniform(0.2, 0.35) * min(w, d), 14.0)  # courtyard: a ring
    return [(0, 0, w, t), (0, d - t, w, d), (0, 0, t, d), (w - t, 0, w, d)]


def _lot_row(
    rng: np.random.Generator, style: Style, length: float, depth: float
) -> list[tuple[float, float, float, float]]:
    """Boxes ``(s0, t0, s1, t1)`` of the buildings on a row of lots ``[0, length] × [0, depth]``
    along a street at t = 0."""
    boxes: list[tuple[float, float, float, float]] = []
    s = 0.0
    while length - s > style.lot_m[0] * 0.5:
        lot = min(rng.uniform(*style.lot_m), length - s)
        if length - s - lot < style.lot_m[0] * 0.5:  # absorb a short remainder
            lot = length - s
        if rng.random() < style.fill:
            gap = rng.uniform(*style.side_gap_m)
            setback = rng.uniform(*style.setback_m)
            bd = depth - setback if rng.random() < style.deep else min(rng.uniform(*style.depth_m), depth - setback)
            bw = lot - gap
            if bw > 4 and bd > 4:
                s0 = s + rng.uniform(0, gap)
                boxes += [
                    (s0 + a0, setback + b0, s0 + a1, setback + b1) for a0, b0, a1, b1 in _building(rng, style, bw, bd)
                ]
        s += lot
    return boxes


def _to_rects(
    boxes: list[tuple[float, float, float, float]], origin: tuple[float, float], along: int, inward: float, sign: float
) -> list[Rect]:
    """Map row boxes to district-frame rectangles. ``along``: 0 when the row runs along u, 1 along v;
    ``origin``: district coordinates of the row start on the street; ``sign``/``inward``: direction
    (+1/-1) of s along the row and of t into the block."""
    rects: list[Rect] = []
    for s0, t0, s1, t1 in boxes:
        cs, ct = origin[along] + sign * (s0 + s1) / 2, origin[1 - along] + inward * (t0 + t1) / 2
        hs, ht = (s1 - s0) / 2, (t1 - t0) / 2
        rects.append((cs, ct, hs, ht) if along == 0 else (ct, cs, ht, hs))
    return rects


def _block(rng: np.random.Generator, style: Style, u0: float, u1: float, v0: float, v1: float) -> list[Rect]:
    """Buildings of one block ``[u0, u1] × [v0, v1]`` (district frame, metres)."""
    if rng.random() < style.park:
        return []
    along = 0 if (u1 - u0) >= (v1 - v0) else 1  # rows run along the long side
    lo, hi = (u0, u1) if along == 0 else (v0, v1)  # long side
    c0, c1 = (v0, v1) if along == 0 else (u0, u1)  # short side (streets of the rows)
    length, width = hi - lo, c1 - c0

    def start(a: float, c: float) -> tuple[float, float]:
        return (a, c) if along == 0 else (c, a)

    rects: list[Rect] = []
    if rng.random() < style.perimeter and width > 30:
        t = min(rng.uniform(*style.depth_m), width / 2.5)
        rects += _to_rects(_lot_row(rng, style, length, t), start(lo, c0), along, +1, +1)
        rects += _to_rects(_lot_row(rng, style, length, t), start(lo, c1), along, -1, +1)
        # the two short sides, between the long rows
        short = 1 - along
        rects += _to_rects(_lot_row(rng, style, width - 2 * t, t), start(lo, c0 + t), short, +1, +1)
        rects += _to_rects(_lot_row(rng, style, width - 2 * t, t), start(hi, c0 + t), short, -1, +1)
        return rects
    if width > 2 * (style.depth_m[0] + style.setback_m[0]):
        rects += _to_rects(_lot_row(rng, style, length, width / 2), start(lo, c0), along, +1, +1)
        rects += _to_rects(_lot_row(rng, style, length, width / 2), start(lo, c1), along, -1, +1)
    else:
        rects += _to_rects(_lot_row(rng, style, length, width), start(lo, c0), along, +1, +1)
    return rects


def _street_grid(rng: np.random.Generator, style: Style, lo: float, hi: float) -> list[tuple[float, float]]:
    """Blocks ``(start, end)`` along one axis of a district frame covering ``[lo, hi]`` (metres):
    blocks of random length separated by streets, every few streets a wide avenue."""
    blocks: list[tuple[float, float]] = []
    pos = lo - rng.uniform(0, style.block_m[1])
    while pos < hi:
        street = rng.uniform(*style.street_m) * (rng.uniform(1.6, 2.5) if rng.random() < 0.12 else 1.0)
        length = rng.uniform(*style.block_m)
        blocks.append((pos + street, pos + street + length))
        pos += street + length
    return blocks


def _rasterize(grid: np.ndarray, label: np.ndarray, district: int, rects: np.ndarray, angle: float) -> None:
    """Draw rotated rectangles (rows ``cx, cy, a, b`` in cell units: centre in index coordinates,
    half sizes along the district axes) into ``grid``, only on cells of ``district``."""
    c, s = np.cos(angle), np.sin(angle)
    n = grid.shape[0]
    for cx, cy, a, b in rects:
        ex, ey = abs(a * c) + abs(b * s), abs(a * s) + abs(b * c)
        i0, i1 = max(int(np.ceil(cx - ex)), 0), min(int(np.floor(cx + ex)) + 1, n)
        j0, j1 = max(int(np.ceil(cy - ey)), 0), min(int(np.floor(cy + ey)) + 1, n)
        if i1 <= i0 or j1 <= j0:
            continue
        dx = np.arange(i0, i1)[:, None] - cx
        dy = np.arange(j0, j1)[None, :] - cy
        inside = (np.abs(dx * c + dy * s) < a) & (np.abs(dy * c - dx * s) < b)
        grid[i0:i1, j0:j1] |= inside & (label[i0:i1, j0:j1] == district)


def _districts(rng: np.random.Generator, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voronoi districts: ``(sites (k, 2) in metres, label (size, size), distance of every cell centre
    to the nearest district border in metres (inf with one district))``."""
    k = int(rng.integers(1, 6))
    extent = size * CELL_M
    sites = rng.uniform(0.1 * extent, 0.9 * extent, size=(k, 2))
    centres = (np.arange(size) + 0.5) * CELL_M
    d2 = (centres[:, None, None] - sites[None, None, :, 0]) ** 2 + (
        centres[None, :, None] - sites[None, None, :, 1]
    ) ** 2
    if k == 1:
        return sites, np.zeros((size, size), dtype=np.int8), np.full((size, size), np.inf)
    order = np.argsort(d2, axis=-1)[..., :2]
    first, second = order[..., 0], order[..., 1]
    d_first = np.take_along_axis(d2, first[..., None], axis=-1)[..., 0]
    d_second = np.take_along_axis(d2, second[..., None], axis=-1)[..., 0]
    gap = np.linalg.norm(sites[first] - sites[second], axis=-1)
    border = (d_second - d_first) / (2 * gap)
    return sites, first.astype(np.int8), border


def _river(rng: np.random.Generator, size: int) -> np.ndarray:
    """Cells of a meandering empty band (river or highway) across the map."""
    extent = size * CELL_M
    centres = (np.arange(size) + 0.5) * CELL_M
    x, y = centres[:, None], centres[None, :]
    p0 = rng.uniform(0.2 * extent, 0.8 * extent, size=2)
    theta = rng.uniform(0, np.pi)
    t = (x - p0[0]) * np.cos(theta) + (y - p0[1]) * np.sin(theta)
    n = -(x - p0[0]) * np.sin(theta) + (y - p0[1]) * np.cos(theta)
    amplitude, wavelength = rng.uniform(0, 120), rng.uniform(600, 1500)
    offset = amplitude * np.sin(2 * np.pi * t / wavelength + rng.uniform(0, 2 * np.pi))
    return np.abs(n - offset) < rng.uniform(15, 45)


def generate_city_map(seed: int, size: int = MAP_SIZE) -> np.ndarray:
    """The city map of ``seed``: ``uint8`` array ``(size, size)`` indexed ``[x, y]``, 1 = building.

    Raises:
        ValueError: negative seed or size < 1.
    """
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    rng = np.random.default_rng(seed)
    sites, label, border = _districts(rng, size)
    grid = np.zeros((size, size), dtype=bool)
    extent = size * CELL_M
    corners = np.array([[0, 0], [extent, 0], [0, extent], [extent, extent]])
    for district in range(len(sites)):
        style = STYLES[int(rng.choice(len(STYLES), p=np.asarray(STYLE_WEIGHTS) / sum(STYLE_WEIGHTS)))]
        angle = 0.0 if rng.random() < 0.4 else float(rng.uniform(-np.pi / 4, np.pi / 4))
        angle += float(rng.normal(0, 0.02))
        c, s = np.cos(angle), np.sin(angle)
        # district frame: (u, v) = R(-angle) (x, y); its u axis points along (c, s) in the map
        uv = corners @ np.array([[c, -s], [s, c]])
        blocks_u = _street_grid(rng, style, uv[:, 0].min(), uv[:, 0].max())
        blocks_v = _street_grid(rng, style, uv[:, 1].min(), uv[:, 1].max())
        rects: list[Rect] = []
        for u0, u1 in blocks_u:
            for v0, v1 in blocks_v:
                probe_uv = np.array([[u0, v0], [u0, v1], [u1, v0], [u1, v1], [(u0 + u1) / 2, (v0 + v1) / 2]])
                probe = probe_uv @ np.array([[c, s], [-s, c]])  # back to map metres
                idx = np.floor(probe / CELL_M).astype(np.int64)
                ok = np.all((idx >= 0) & (idx < size), axis=1)
                if not np.any(label[idx[ok, 0], idx[ok, 1]] == district):
                    continue
                rects += _block(rng, style, u0, u1, v0, v1)
        if not rects:
            continue
        r = np.asarray(rects, dtype=np.float64)
        centre_xy = r[:, :2] @ np.array([[c, s], [-s, c]])
        cells = np.column_stack([centre_xy / CELL_M - 0.5, r[:, 2:] / CELL_M])
        _rasterize(grid, label, district, cells, angle)
    avenue = rng.uniform(15, 32)
    grid &= border >= avenue / 2
    if rng.random() < 0.35:
        grid &= ~_river(rng, size)
    return grid.astype(np.uint8)


def crop(city_map: np.ndarray, size: int = 400, rng: np.random.Generator | None = None) -> np.ndarray:
    """A random ``size × size`` crop of ``city_map`` (a copy), its corner drawn from ``rng``
    (``None``: a fresh, non-reproducible generator).

    Raises:
        ValueError: the map is smaller than ``size``.
    """
    if rng is None:
        rng = np.random.default_rng()
    nx, ny = city_map.shape
    if nx < size or ny < size:
        raise ValueError(f"cannot crop {size}x{size} from a {nx}x{ny} map")
    x0 = int(rng.integers(0, nx - size + 1))
    y0 = int(rng.integers(0, ny - size + 1))
    return city_map[x0 : x0 + size, y0 : y0 + size].copy()
