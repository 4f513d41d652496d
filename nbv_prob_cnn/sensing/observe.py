"""Simulated depth observation against a ground-truth grid (docs/method.md#sensor-and-simulated-observation).

Rays leave the centre of the camera cell through a pinhole pixel grid dense enough that
neighbouring rays are at most half a cell apart at ``R_max``. Each ray is traversed exactly,
cell by cell (Amanatides–Woo), all rays at once: a traversed cell becomes known if the ray
enters it at a distance ``<= R_max`` (so no point of a newly known cell lies beyond
``R_max``); the first ground-truth-occupied cell becomes occupied and stops the ray; leaving
the grid stops the ray.

Positions are in grid index coordinates: the centre of cell ``i`` is at ``i``.

Two backends trace the rays: :func:`trace_rays` (numpy, the reference) and the OpenCL kernel
``traverse.cl``, which repeats the same operations in the same precision (double where the
device has it) and is used by default when an OpenCL device exists.

With a depth-noise model the same traversal runs to the sensor's maximum range (not ``R_max``)
or out of the grid, and the cells are labelled from the measured depth of each ray
(:func:`measure_rays`); see ``docs/sensing.md``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
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


@dataclass
class RayTrace:
    """The cells rays traverse (Amanatides–Woo), one record per (ray, cell), in traversal order
    per ray, and how each ray ended.

    Attributes:
        ray: ``(R,)`` ray index of each record.
        cell: ``(R,)`` flat cell index of each record.
        t_enter: ``(R,)`` distance at which the ray enters the cell (0 for the origin's cell).
        t_exit: ``(R,)`` distance at which it leaves the cell (= ``t_enter`` of the next record).
        hit: ``(K,)`` whether the ray stopped at a ``stop`` cell within its limit.
        depth: ``(K,)`` where the ray ended: ``t_enter`` of its stop cell when ``hit``, else the
            distance at which it left the grid or, when the limit came first, the limit.
        left_grid: ``(K,)`` whether the ray ended by leaving the grid within its limit.
        hit_cell: ``(K, dims)`` index of the stop cell (-1 where none).
    """

    ray: np.ndarray
    cell: np.ndarray
    t_enter: np.ndarray
    t_exit: np.ndarray
    hit: np.ndarray
    depth: np.ndarray
    left_grid: np.ndarray
    hit_cell: np.ndarray


def trace_rays(
    shape: tuple[int, ...],
    origin: np.ndarray,
    directions: np.ndarray,
    limit: float | np.ndarray,
    stop: np.ndarray | None,
) -> RayTrace:
    """Exact voxel traversal (Amanatides–Woo) of rays from one origin, all rays at once.

    The one traversal of the simulated sensor: the exact observation keeps the cells entered
    within ``R_max``; the noisy one traces to the sensor's maximum range and labels the cells up
    to the measured depth.

    Args:
        shape: grid shape.
        origin: ray origin in index coordinates (cell ``i`` spans ``[i-0.5, i+0.5]``).
        directions: ``(K, dims)`` unit vectors.
        limit: a cell is included if the ray enters it at distance ``<= limit`` (one value, or
            one per ray).
        stop: flat boolean grid; a ray includes the first ``True`` cell and stops there
            (None: rays stop only at the grid's border or their limit).
    """
    dims = len(shape)
    shape_arr = np.array(shape, dtype=np.int64)
    strides = np.array([int(np.prod(shape[i + 1 :])) for i in range(dims)], dtype=np.int64)
    p = np.asarray(origin, dtype=np.float64) + 0.5
    d = np.asarray(directions, dtype=np.float64)
    k = d.shape[0]
    limits = np.broadcast_to(np.asarray(limit, dtype=np.float64), (k,)).copy()
    cell = np.broadcast_to(np.floor(p).astype(np.int64), (k, dims)).copy()
    step = np.where(d > 0, 1, -1).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(d != 0, 1.0 / d, np.inf)
        t_max = np.where(d != 0, ((cell + (step > 0)) - p) * inv, np.inf)
    t_delta = np.abs(inv)
    t_enter = np.zeros(k)
    rows = np.arange(k)
    hit = np.zeros(k, dtype=bool)
    depth = limits.copy()
    left_grid = np.zeros(k, dtype=bool)
    hit_cell = np.full((k, dims), -1, dtype=np.int64)
    records: list[tuple[np.ndarray, ...]] = []
    while rows.size:
        in_grid = np.all((cell >= 0) & (cell < shape_arr), axis=1)
        in_range = t_enter <= limits[rows]
        gone = ~in_grid & in_range  # left the grid before reaching the limit
        depth[rows[gone]] = t_enter[gone]
        left_grid[rows[gone]] = True
        keep = in_grid & in_range
        rows, cell, t_max, t_delta, t_enter, step = (
            rows[keep], cell[keep], t_max[keep], t_delta[keep], t_enter[keep], step[keep],
        )  # fmt: skip
        if not rows.size:
            break
        flat = cell @ strides
        t_exit = t_max.min(axis=1)
        records.append((rows, flat, t_enter, t_exit))
        if stop is not None:
            stopped = stop[flat]
            hit[rows[stopped]] = True
            depth[rows[stopped]] = t_enter[stopped]
            hit_cell[rows[stopped]] = cell[stopped]
            go = ~stopped
            rows, cell, t_max, t_delta, t_enter, step = (
                rows[go], cell[go], t_max[go], t_delta[go], t_enter[go], step[go],
            )  # fmt: skip
        axis = np.argmin(t_max, axis=1)
        idx = np.arange(rows.size)
        t_enter = t_max[idx, axis]
        cell[idx, axis] += step[idx, axis]
        t_max[idx, axis] += t_delta[idx, axis]
    if records:
        ray, flat_cells, enter, leave = (np.concatenate(parts) for parts in zip(*records, strict=True))
    else:
        ray, flat_cells = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        enter, leave = np.zeros(0), np.zeros(0)
    return RayTrace(ray, flat_cells, enter, leave, hit, depth, left_grid, hit_cell)


def traverse(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, r_max: float, stop: np.ndarray | None
) -> np.ndarray:
    """Flat indices of the cells the rays traverse within ``r_max`` (:func:`trace_rays`), with repeats."""
    return trace_rays(shape, origin, directions, r_max, stop).cell


@functools.lru_cache(maxsize=1)
def _traverse_program():
    """The built ``traverse.cl`` (runtime, program, real dtype: float64 where the device has it)."""
    from nbv_prob_cnn.basics.cl_device import cl_runtime

    runtime = cl_runtime()
    options = ("-DUSE_DOUBLE",) if runtime.has_fp64 else ()
    program = runtime.build(Path(__file__).with_name("traverse.cl"), options)
    return runtime, program, np.float64 if runtime.has_fp64 else np.float32


def _traverse_kernel():
    runtime, program, real = _traverse_program()
    return runtime, runtime.cl.Kernel(program, "traverse"), real


def traverse_opencl(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, r_max: float, stop: np.ndarray
) -> np.ndarray:
    """Same as :func:`traverse` on the OpenCL device; returns the unique flat indices."""
    runtime, kernel, real = _traverse_kernel()
    cl = runtime.cl
    mf = cl.mem_flags
    shape3, p, dirs = _kernel_geometry(shape, origin, directions, real)
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
            cell within ``sensor.r_max``. Otherwise (:func:`measure_rays`, numpy) each ray is
            traced with the same traversal to the model's maximum range or out of the grid; its
            depth (first occupied cell, or the room's wall) is perturbed by the model (axial
            noise, range limits, grazing angles from the grid's surface normal, dropouts; no
            lateral/edge terms at this level); the ray labels empty the cells before the
            measured depth and occupied the cell at it. A ray without a return labels nothing.
            ``sensor.r_max`` (the planner's range) does not limit a noisy ray.
        rng: generator of the noise (seed it for repeatable runs); needed with ``noise``.
        resolution_m: cell size in metres; needed with ``noise`` (its parameters are metric).
        room_margin_m: with ``noise``, walls this far outside the grid (as ``sim_camera``'s
            room, all sides): a ray that leaves the grid returns from the wall it meets, if that
            lies within range, so the cells it crossed are measured empty. ``None``: no walls
            (such rays return nothing).

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
        measure = functools.partial(measure_rays, truth, pos, noise=noise, rng=rng, resolution_m=float(resolution_m),
                                    margin_cells=margin, backend=backend)  # fmt: skip
        return _observe_measured(state, rays, measure)
    if backend == "opencl":
        cells = traverse_opencl(state.shape, pos, rays, sensor.r_max, flat_truth)
    else:
        cells = np.unique(traverse(state.shape, pos, rays, sensor.r_max, flat_truth.astype(bool)))
    flat_state = state.reshape(-1)
    newly = int(np.count_nonzero(flat_state[cells] == -1))
    flat_state[cells] = flat_truth[cells].astype(np.int8)
    return newly


def _observe_measured(
    state: np.ndarray,
    rays: np.ndarray,
    measure: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    chunk: int = 16384,
) -> int:
    """:func:`observe` with a noise model: label ``state`` with the empty and occupied cells that
    ``measure`` (:func:`measure_rays` of the view) gives for ``rays``, ``chunk`` rays at a time."""
    empty_parts, occupied_parts = [], []
    for first_ray in range(0, len(rays), chunk):
        empty, occupied = measure(rays[first_ray : first_ray + chunk])
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


def wall_distance(shape: tuple[int, ...], pos: np.ndarray, rays: np.ndarray, margin_cells: float) -> tuple:
    """Distance along each ray to the walls of a room ``margin_cells`` outside the grid (an
    axis-aligned box around cells ``-0.5 - margin .. n - 0.5 + margin``), and the cosine of the
    incidence there (the ray's component along the normal of the wall it meets)."""
    upper = np.array(shape, dtype=np.float64) - 0.5 + margin_cells
    lower = np.full(len(shape), -0.5 - margin_cells)
    bound = np.where(rays > 0, upper, lower)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_axis = np.where(rays != 0, (bound - pos) / rays, np.inf)
    axis = np.argmin(t_axis, axis=1)
    index = np.arange(len(rays))
    return t_axis[index, axis], np.abs(rays[index, axis])


def surface_cosine(truth: np.ndarray, cells: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Cosine between each ray and the surface normal at its hit cell, the normal being the
    (negative) central-difference gradient of the occupancy (1 where the gradient vanishes)."""
    shape = np.array(truth.shape)
    normal = np.zeros(rays.shape)
    for axis in range(truth.ndim):
        up, down = cells.copy(), cells.copy()
        up[:, axis] = np.minimum(up[:, axis] + 1, shape[axis] - 1)
        down[:, axis] = np.maximum(down[:, axis] - 1, 0)
        normal[:, axis] = truth[tuple(down.T)].astype(float) - truth[tuple(up.T)].astype(float)
    norm = np.linalg.norm(normal, axis=1)
    return np.where(norm > 0, np.abs(np.sum(normal * rays, axis=1)) / np.maximum(norm, 1e-12), 1.0)


def measure_rays(
    truth: np.ndarray,
    pos: np.ndarray,
    rays: np.ndarray,
    noise: SensorNoise,
    rng: np.random.Generator,
    resolution_m: float,
    margin_cells: float | None = None,
    backend: str = "numpy",
) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of the cells ``rays`` measure empty, and of those they measure occupied.

    Each ray is traced exactly (:func:`trace_rays`, as the exact observation) to the sensor's
    maximum range or out of the grid, where it meets the room's walls when ``margin_cells`` is
    given. Its depth (the entry distance of the first occupied cell, or the wall's distance) goes
    through the noise model (range limits, grazing incidence, dropouts, axial noise); a ray
    without a return labels nothing. A returned ray labels empty the cells it leaves at or before
    the measured depth and occupied the cell that contains the measured point (none when that
    point lies outside the grid). With every noise effect off and every ray returning, this
    labels exactly the cells of the exact observation (the measured depth is the exact one).

    ``backend`` ``"numpy"`` (the reference) or ``"opencl"`` (kernels ``trace_end`` and
    ``label_measured`` of ``traverse.cl``, the same operations in the same precision); the noise
    is drawn here in both cases, so a seeded generator gives both the same labels.
    """
    shape = truth.shape
    flat_truth = truth.reshape(-1).astype(bool)
    limit = noise.max_range_m / resolution_m  # [cells]; inf: the grid's border ends the rays
    if backend == "opencl":
        trace = None
        depth, hit, left_grid, hit_cell = _trace_end_opencl(shape, pos, rays, limit, flat_truth)
    else:
        trace = trace_rays(shape, pos, rays, limit, flat_truth)
        depth, hit, left_grid, hit_cell = trace.depth, trace.hit, trace.left_grid, trace.hit_cell
    depth_cells = np.where(hit, depth, 0.0)
    cos_incidence = np.ones(len(rays))
    cos_incidence[hit] = surface_cosine(truth, hit_cell[hit], rays[hit])
    if margin_cells is not None:  # walls outside the grid: rays that leave it see them
        to_wall, wall_cos = wall_distance(shape, pos, rays, margin_cells)
        walls = left_grid & (to_wall <= limit)
        depth_cells = np.where(walls, to_wall, depth_cells)
        cos_incidence = np.where(walls, wall_cos, cos_incidence)
    depth_m = depth_cells * resolution_m
    measured_m = noise.perturb_ranges(depth_m, rng, cos_incidence)  # 0 = no return
    # unperturbed depths keep their exact value in cells (no rounding through metres)
    measured = np.where(measured_m == depth_m, depth_cells, measured_m / resolution_m)
    if trace is None:
        return _label_measured_opencl(shape, pos, rays, measured)
    returned = measured > 0
    m = measured[trace.ray]
    take = returned[trace.ray]
    empty = trace.cell[take & (trace.t_exit <= m)]
    end = trace.cell[take & (trace.t_enter <= m) & (m < trace.t_exit)]
    # a return behind the traced part of a ray (noise beyond its surface): trace it on, through it
    beyond = returned & trace.hit & (measured >= _last_exit(trace, len(rays)))
    if beyond.any():
        rows = np.flatnonzero(beyond)
        extra = trace_rays(shape, pos, rays[rows], measured[rows], None)
        m_extra = measured[rows][extra.ray]
        empty = np.concatenate([empty, extra.cell[extra.t_exit <= m_extra]])
        end = np.concatenate([end, extra.cell[(extra.t_enter <= m_extra) & (m_extra < extra.t_exit)]])
    return np.unique(empty).astype(np.int64), np.unique(end).astype(np.int64)


def _last_exit(trace: RayTrace, n_rays: int) -> np.ndarray:
    """Per ray, the exit distance of its last traced cell (-inf for a ray without records)."""
    last = np.full(n_rays, -np.inf)
    np.maximum.at(last, trace.ray, trace.t_exit)
    return last


def _kernel_geometry(shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, real) -> tuple:
    """The kernels' 3D view of a 2D/3D grid: padded shape, origin (+0.5) and directions."""
    shape3 = tuple(shape) + (1,) * (3 - len(shape))
    p = np.zeros(3)
    p[: len(shape)] = np.asarray(origin, dtype=np.float64) + 0.5
    p[len(shape) :] = 0.5
    dirs = np.zeros((directions.shape[0], 3), dtype=real)
    dirs[:, : directions.shape[1]] = directions
    return shape3, p, dirs


def _trace_end_opencl(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, limit: float, stop: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`trace_rays`' ``depth, hit, left_grid, hit_cell`` on the OpenCL device."""
    runtime, program, real = _traverse_program()
    cl, mf = runtime.cl, runtime.cl.mem_flags
    shape3, p, dirs = _kernel_geometry(shape, origin, directions, real)
    k = dirs.shape[0]
    depth, status, hit = np.zeros(k, dtype=real), np.zeros(k, dtype=np.int32), np.zeros(k, dtype=np.int64)
    stop_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(stop, np.uint8))
    dir_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=dirs)
    out = [cl.Buffer(runtime.context, mf.WRITE_ONLY, a.nbytes) for a in (depth, status, hit)]
    kernel = cl.Kernel(program, "trace_end")
    kernel.set_args(
        stop_buf, *(np.int32(n) for n in shape3), *(real(v) for v in p), dir_buf, np.int32(k),
        real(min(limit, np.finfo(real).max)), *out,
    )  # fmt: skip
    cl.enqueue_nd_range_kernel(runtime.queue, kernel, (k,), None)
    for host, buf in zip((depth, status, hit), out, strict=True):
        cl.enqueue_copy(runtime.queue, host, buf)
    runtime.queue.finish()
    hit_cell = np.full((k, len(shape)), -1, dtype=np.int64)
    is_hit = status == 1
    hit_cell[is_hit] = np.stack(np.unravel_index(hit[is_hit], shape), axis=1)
    depth64 = depth.astype(np.float64)
    depth64[status == 0] = limit
    return depth64, is_hit, status == 2, hit_cell


def _label_measured_opencl(
    shape: tuple[int, ...], origin: np.ndarray, directions: np.ndarray, measured: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The labels of :func:`measure_rays` from per-ray measured depths, on the OpenCL device."""
    runtime, program, real = _traverse_program()
    cl, mf = runtime.cl, runtime.cl.mem_flags
    shape3, p, dirs = _kernel_geometry(shape, origin, directions, real)
    size = int(np.prod(shape))
    empty, occupied = np.zeros(size, dtype=np.uint8), np.zeros(size, dtype=np.uint8)
    dir_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=dirs)
    m_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(measured, real))
    bufs = [cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for a in (empty, occupied)]
    kernel = cl.Kernel(program, "label_measured")
    kernel.set_args(*(np.int32(n) for n in shape3), *(real(v) for v in p), dir_buf, np.int32(dirs.shape[0]),
                    m_buf, *bufs)  # fmt: skip
    cl.enqueue_nd_range_kernel(runtime.queue, kernel, (dirs.shape[0],), None)
    for host, buf in zip((empty, occupied), bufs, strict=True):
        cl.enqueue_copy(runtime.queue, host, buf)
    runtime.queue.finish()
    return np.flatnonzero(empty), np.flatnonzero(occupied)
