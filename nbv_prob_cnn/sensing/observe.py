"""Simulated depth observation against a ground-truth grid (SPEC §2).

Rays leave the centre of the camera cell through a pinhole pixel grid dense enough that
neighbouring rays are at most half a cell apart at ``R_max``. Each ray is traversed exactly,
cell by cell (Amanatides–Woo), all rays at once: a traversed cell becomes known if the ray
enters it at a distance ``<= R_max`` (so no point of a newly known cell lies beyond
``R_max``); the first ground-truth-occupied cell becomes occupied and stops the ray; leaving
the grid stops the ray.

Positions are in grid index coordinates: the centre of cell ``i`` is at ``i``.

Two backends trace the rays: :func:`traverse` (numpy, the reference) and the OpenCL kernel
``traverse.cl``, which repeats the same operations in the same precision (double where the
device has it) and is used by default when an OpenCL device exists.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.camera import Sensor, matrix_from_quaternion
from nbv_prob_cnn.basics.grid import check_ground_truth, check_state
from nbv_prob_cnn.basics.modes import Backend
from nbv_prob_cnn.sensing.sensor_noise import SensorNoise

#: Largest spacing (cells) between neighbouring simulated rays at ``R_max``.
RAY_SPACING_CELLS = 0.5


def camera_rays(sensor: Sensor, dims: int) -> np.ndarray:
    """Unit ray directions in the camera frame (2D: +x forward; 3D: optical, +z forward).

    The pixel pitch is chosen so that the angular step is at most ``0.5 / R_max`` rad.
    """
    focal = max(sensor.focal_px, sensor.r_max / RAY_SPACING_CELLS)
    half_w = math.tan(math.radians(sensor.hfov_deg) / 2.0)
    nx = max(2, math.ceil(2.0 * half_w * focal) + 1)
    xs = np.linspace(-half_w, half_w, nx)
    if dims == 2:
        rays = np.stack([np.ones_like(xs), xs], axis=1)
    else:
        if sensor.vfov_deg is None:
            raise ValueError("sensor: a 3D sensor needs vfov_deg")
        half_h = math.tan(math.radians(sensor.vfov_deg) / 2.0)
        ny = max(2, math.ceil(2.0 * half_h * focal) + 1)
        ys = np.linspace(-half_h, half_h, ny)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        rays = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def world_rays(orientation: np.ndarray | float, sensor: Sensor, dims: int) -> np.ndarray:
    """Camera rays rotated into grid axes for one orientation (yaw in 2D, quaternion in 3D)."""
    rays = camera_rays(sensor, dims)
    if dims == 2:
        yaw = float(orientation)
        if not math.isfinite(yaw):
            raise ValueError(f"orientation: expected a finite yaw angle, got {orientation}")
        c, s = math.cos(yaw), math.sin(yaw)
        rot = np.array([[c, -s], [s, c]])
    else:
        rot = matrix_from_quaternion(np.asarray(orientation))
    return rays @ rot.T


def traverse(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, r_max: float, stop: np.ndarray | None
) -> np.ndarray:
    """Flat indices of the cells the rays traverse (Amanatides–Woo), with repeats.

    Args:
        shape: grid shape.
        origin: ray origin in index coordinates (cell ``i`` spans ``[i-0.5, i+0.5]``).
        directions: ``(K, dims)`` unit vectors.
        r_max: a cell is included if the ray enters it at distance ``<= r_max``.
        stop: flat boolean grid; a ray includes the first ``True`` cell and stops there.
    """
    dims = len(shape)
    shape_arr = np.array(shape, dtype=np.int64)
    strides = np.array([int(np.prod(shape[i + 1 :])) for i in range(dims)], dtype=np.int64)
    p = np.asarray(origin, dtype=np.float64) + 0.5
    d = np.asarray(directions, dtype=np.float64)
    k = d.shape[0]
    cell = np.broadcast_to(np.floor(p).astype(np.int64), (k, dims)).copy()
    step = np.where(d > 0, 1, -1).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(d != 0, 1.0 / d, np.inf)
        t_max = np.where(d != 0, ((cell + (step > 0)) - p) * inv, np.inf)
    t_delta = np.abs(inv)
    t_enter = np.zeros(k)
    rows = np.arange(k)
    visited = []
    while rows.size:
        inside = np.all((cell >= 0) & (cell < shape_arr), axis=1) & (t_enter <= r_max)
        rows, cell, t_max, t_delta, t_enter, step = (
            rows[inside],
            cell[inside],
            t_max[inside],
            t_delta[inside],
            t_enter[inside],
            step[inside],
        )
        if not rows.size:
            break
        flat = cell @ strides
        visited.append(flat)
        if stop is not None:
            go = ~stop[flat]
            rows, cell, t_max, t_delta, t_enter, step = (
                rows[go],
                cell[go],
                t_max[go],
                t_delta[go],
                t_enter[go],
                step[go],
            )
        axis = np.argmin(t_max, axis=1)
        idx = np.arange(rows.size)
        t_enter = t_max[idx, axis]
        cell[idx, axis] += step[idx, axis]
        t_max[idx, axis] += t_delta[idx, axis]
    return np.concatenate(visited) if visited else np.zeros(0, dtype=np.int64)


@functools.lru_cache(maxsize=1)
def _traverse_kernel():
    from nbv_prob_cnn.basics.cl_device import cl_runtime

    runtime = cl_runtime()
    options = ("-DUSE_DOUBLE",) if runtime.has_fp64 else ()
    program = runtime.build(Path(__file__).with_name("traverse.cl"), options)
    return runtime, runtime.cl.Kernel(program, "traverse"), np.float64 if runtime.has_fp64 else np.float32


def traverse_opencl(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, r_max: float, stop: np.ndarray
) -> np.ndarray:
    """Same as :func:`traverse` on the OpenCL device; returns the unique flat indices."""
    runtime, kernel, real = _traverse_kernel()
    cl = runtime.cl
    mf = cl.mem_flags
    shape3 = tuple(shape) + (1,) * (3 - len(shape))
    p = np.zeros(3)
    p[: len(shape)] = np.asarray(origin, dtype=np.float64) + 0.5
    p[len(shape) :] = 0.5
    dirs = np.zeros((directions.shape[0], 3), dtype=real)
    dirs[:, : directions.shape[1]] = directions
    stop_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(stop, np.uint8))
    dir_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=dirs)
    seen = np.zeros(int(np.prod(shape)), dtype=np.uint8)
    seen_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=seen)
    kernel.set_args(
        stop_buf, *(np.int32(n) for n in shape3), *(real(v) for v in p), dir_buf,
        np.int32(dirs.shape[0]), real(r_max), seen_buf,
    )  # fmt: skip
    cl.enqueue_nd_range_kernel(runtime.queue, kernel, (dirs.shape[0],), None)
    cl.enqueue_copy(runtime.queue, seen, seen_buf)
    runtime.queue.finish()
    return np.flatnonzero(seen)


def observe(
    state: np.ndarray,
    ground_truth: np.ndarray,
    position: np.ndarray,
    orientation: np.ndarray | float,
    sensor: Sensor,
    backend: Backend = "auto",
    noise: SensorNoise | None = None,
    rng: np.random.Generator | None = None,
    resolution_m: float | None = None,
    room_margin_m: float | None = None,
) -> int:
    """Simulate one depth view and merge it into ``state`` in place.

    Args:
        state: ternary ``int8`` grid, updated in place (must be C-contiguous ``int8``).
        ground_truth: binary grid ``D`` of the same shape.
        position: camera position in index coordinates, inside the grid.
        orientation: yaw (2D, radians) or quaternion ``(x, y, z, w)`` (3D).
        sensor: field of view and range (cells).
        backend: ``"opencl"``, ``"numpy"`` or ``"auto"`` (OpenCL if a device works).
        noise: a depth-sensor model (:mod:`nbv_prob_cnn.sensing.sensor_noise`, the one the simulated
            depth camera uses); ``None`` or ``ideal`` = exact observation of every traversed
            cell. Otherwise each ray measures the distance to its first occupied cell, the
            model perturbs it (axial noise, range limits, grazing angles from the grid's surface
            normal, dropouts; no lateral/edge terms at this level), and the ray labels the cells
            before the measured depth empty and the cell at it occupied (a ray without a
            return labels nothing). Runs on numpy.
        rng: generator of the noise (seed it for repeatable runs); needed with ``noise``.
        resolution_m: cell size in metres; needed with ``noise`` (its parameters are metric).
        room_margin_m: with ``noise``, walls this far outside the grid (as ``sim_camera``'s
            room): a ray that leaves the grid within range returns from the wall, so the cells
            it crossed are measured empty. ``None``: no walls (such rays return nothing).

    Returns:
        The number of cells that were unknown and are now known.
    """
    checked = check_state(state)
    if checked is not state:
        raise ValueError("state: must be a C-contiguous int8 array (it is updated in place)")
    truth = check_ground_truth(ground_truth, state.shape)
    pos = np.asarray(position, dtype=np.float64).reshape(-1)
    if pos.shape[0] != state.ndim or not np.all(np.isfinite(pos)):
        raise ValueError(f"position: expected {state.ndim} finite coordinates, got {pos.tolist()}")
    if np.any(pos < -0.5) or np.any(pos >= np.array(state.shape) - 0.5):
        raise ValueError(f"position: {pos.tolist()} lies outside the grid of shape {state.shape}")
    if backend not in ("auto", "opencl", "numpy"):
        raise ValueError(f"backend: expected 'auto', 'opencl' or 'numpy', got {backend!r}")
    if backend == "auto":
        from nbv_prob_cnn.basics.cl_device import opencl_available

        backend = "opencl" if opencl_available() else "numpy"
    rays = world_rays(orientation, sensor, state.ndim)
    flat_truth = truth.reshape(-1)
    if noise is not None and not noise.is_ideal:
        if rng is None or resolution_m is None or not resolution_m > 0:
            raise ValueError("observe: a noise model needs rng and a positive resolution_m")
        margin = None if room_margin_m is None else float(room_margin_m) / float(resolution_m)
        return _observe_noisy(state, truth, pos, rays, sensor.r_max, noise, rng, float(resolution_m), margin)
    if backend == "opencl":
        cells = traverse_opencl(state.shape, pos, rays, sensor.r_max, flat_truth)
    else:
        cells = np.unique(traverse(state.shape, pos, rays, sensor.r_max, flat_truth.astype(bool)))
    flat_state = state.reshape(-1)
    newly = int(np.count_nonzero(flat_state[cells] == -1))
    flat_state[cells] = flat_truth[cells].astype(np.int8)
    return newly


def _observe_noisy(
    state: np.ndarray,
    truth: np.ndarray,
    pos: np.ndarray,
    rays: np.ndarray,
    r_max: float,
    noise: SensorNoise,
    rng: np.random.Generator,
    resolution_m: float,
    margin_cells: float | None = None,
    chunk: int = 1024,
) -> int:
    """:func:`observe` with a noise model: rays sampled every quarter cell (numpy, ``chunk`` rays at a time)."""
    shape = np.array(state.shape)
    t = np.arange(0.0, float(r_max) + 1e-9, 0.25)  # distances along the ray [cells]
    empty_parts, occupied_parts = [], []
    for first_ray in range(0, len(rays), chunk):
        part = rays[first_ray : first_ray + chunk]
        empty, occupied = _noisy_rays(state.shape, shape, truth, pos, part, t, noise, rng, resolution_m, margin_cells)
        empty_parts.append(empty)
        occupied_parts.append(occupied)
    empty_cells = np.unique(np.concatenate(empty_parts))
    occupied_cells = np.unique(np.concatenate(occupied_parts))
    flat_state = state.reshape(-1)
    known = np.union1d(empty_cells, occupied_cells)
    newly = int(np.count_nonzero(flat_state[known] == -1))
    flat_state[empty_cells] = 0
    flat_state[occupied_cells] = 1  # a surface seen by one ray wins over another ray's free space
    return newly


def _noisy_rays(
    dims: tuple[int, ...],
    shape: np.ndarray,
    truth: np.ndarray,
    pos: np.ndarray,
    rays: np.ndarray,
    t: np.ndarray,
    noise: SensorNoise,
    rng: np.random.Generator,
    resolution_m: float,
    margin_cells: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of the cells some of ``rays`` measure empty, and of those they measure occupied."""
    cells = np.floor(pos[None, None, :] + rays[:, None, :] * t[None, :, None] + 0.5).astype(np.int64)
    inside = np.all((cells >= 0) & (cells < shape), axis=-1)
    inside &= np.cumprod(inside, axis=1).astype(bool)  # a ray that left the grid stays out
    flat = np.where(inside, np.ravel_multi_index(tuple(np.clip(cells, 0, shape - 1).transpose(2, 0, 1)), dims), 0)
    occupied = inside & truth.reshape(-1)[flat].astype(bool)
    hit = occupied.any(axis=1)
    first = np.argmax(occupied, axis=1)
    # surface normal at the hit cell: the (negative) gradient of the occupancy
    hit_cells = cells[np.arange(len(rays)), first]
    normal = np.zeros(rays.shape)
    for axis in range(len(dims)):
        up, down = hit_cells.copy(), hit_cells.copy()
        up[:, axis] = np.clip(up[:, axis] + 1, 0, shape[axis] - 1)
        down[:, axis] = np.clip(down[:, axis] - 1, 0, shape[axis] - 1)
        up, down = np.clip(up, 0, shape - 1), np.clip(down, 0, shape - 1)
        normal[:, axis] = truth[tuple(down.T)].astype(float) - truth[tuple(up.T)].astype(float)
    norm = np.linalg.norm(normal, axis=1)
    cos_incidence = np.where(norm > 0, np.abs(np.sum(normal * rays, axis=1)) / np.maximum(norm, 1e-12), 1.0)
    depth_cells = np.where(hit, t[first], 0.0)
    if margin_cells is not None:  # a wall outside the grid: rays that leave it see the wall
        n_inside = inside.sum(axis=1)
        left = ~hit & (n_inside < len(t))
        t_exit = t[np.minimum(n_inside, len(t) - 1)]
        depth_cells = np.where(left, t_exit + margin_cells, depth_cells)
        wall_cos = np.max(np.abs(rays), axis=1)  # an axis-aligned wall: the largest direction component
        cos_incidence = np.where(left, wall_cos, cos_incidence)
    depth_m = depth_cells * resolution_m
    measured = noise.perturb_ranges(depth_m, rng, cos_incidence) / resolution_m  # [cells], 0 = no return
    returned = measured > 0
    before = inside & returned[:, None] & (t[None, :] < measured[:, None] - 0.5)
    end = np.floor(pos[None, :] + rays * measured[:, None] + 0.5).astype(np.int64)
    end_ok = returned & np.all((end >= 0) & (end < shape), axis=1)
    occupied_cells = np.ravel_multi_index(tuple(end[end_ok].T), dims).astype(np.int64)
    return flat[before].astype(np.int64), occupied_cells
