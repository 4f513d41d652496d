"""Rays through one camera's own image, for scoring a given pose (docs/method.md#scoring-given-poses).

The view search casts one fixed set of rays from every origin (:func:`~nbv_prob_cnn.gain.ray_directions`)
and sums those inside each candidate frustum: with the 3D default of ``N_rays`` 4 (56 rays) only 2 to
6 lie inside a 57° × 45° depth camera, too few to tell poses a few centimetres apart. A pose given
to be scored has one frustum: its rays can all lie inside it. :func:`frustum_rays` lays them on a
pinhole grid of ``across`` columns spanning the field of view, each carrying its solid angle, so
that the pose's gain ``Σ Ω_r G_r`` is the frustum's solid angle weighted by the rays' gains (in
steradians).
"""

from __future__ import annotations

import math

import numpy as np


def _rectangle_solid_angle(x0: np.ndarray, x1: np.ndarray, y0: np.ndarray, y1: np.ndarray) -> np.ndarray:
    """Solid angle [sr] of the rectangles ``[x0, x1] × [y0, y1]`` of the image plane ``z = 1``
    seen from the centre of projection (exact: the corners of ``atan(x y / sqrt(1 + x² + y²))``)."""

    def corner(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.arctan(x * y / np.sqrt(1.0 + x * x + y * y))

    return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0)


def frustum_rays(
    dims: int, across: int, hfov_deg: float, vfov_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Ray directions through a pinhole image spanning the field of view, in the camera frame, and
    the solid angle (3D, steradians) or angle (2D, radians) each ray stands for.

    3D: ``across`` columns by ``down = max(1, round(across · tan(vfov/2) / tan(hfov/2)))`` rows of
    equal pixels on the image plane ``z = 1`` (optical frame: x right, y down, z forward), a ray
    through each pixel centre, row by row (top row first, left to right); the weights are the
    pixels' exact solid angles, which sum to the frustum's, ``4 atan(a b / sqrt(1 + a² + b²))`` with
    ``a, b`` the tangents of the half fields of view. 2D: ``across`` rays at equal angles across
    ``hfov`` about the camera's +x axis (counter-clockwise first from the right edge), each
    standing for ``hfov / across`` radians.

    Returns:
        ``(directions (R, dims) float64 unit vectors, weights (R,) float64)``.

    Raises:
        ValueError: ``dims`` not 2 or 3, ``across`` < 1, or a field of view outside (0, 180) deg.
    """
    if dims not in (2, 3):
        raise ValueError(f"dims: expected 2 or 3, got {dims}")
    if not isinstance(across, (int, np.integer)) or isinstance(across, bool) or across < 1:
        raise ValueError(f"across: expected a positive number of rays across the image, got {across!r}")
    if not 0.0 < hfov_deg < 180.0:
        raise ValueError(f"hfov_deg: expected a field of view in (0, 180) deg, got {hfov_deg}")
    if dims == 2:
        half = math.radians(hfov_deg) / 2.0
        angles = -half + (np.arange(across) + 0.5) * (2.0 * half / across)
        return np.stack([np.cos(angles), np.sin(angles)], axis=1), np.full(across, 2.0 * half / across)
    if vfov_deg is None or not 0.0 < vfov_deg < 180.0:
        raise ValueError(f"vfov_deg: expected a field of view in (0, 180) deg in 3D, got {vfov_deg}")
    a, b = math.tan(math.radians(hfov_deg) / 2.0), math.tan(math.radians(vfov_deg) / 2.0)
    down = max(1, round(across * b / a))
    xs = np.linspace(-a, a, across + 1)
    ys = np.linspace(-b, b, down + 1)
    x0, y0 = np.meshgrid(xs[:-1], ys[:-1])  # rows of y (top = -b: image up is -y), columns of x
    x1, y1 = np.meshgrid(xs[1:], ys[1:])
    weights = _rectangle_solid_angle(x0, x1, y0, y1).reshape(-1)
    centres = np.stack([(x0 + x1) / 2.0, (y0 + y1) / 2.0, np.ones_like(x0)], axis=-1).reshape(-1, 3)
    return centres / np.linalg.norm(centres, axis=1, keepdims=True), weights
