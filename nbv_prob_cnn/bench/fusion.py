"""Throughput of the TSDF integrator (a benchmark, not a test): wired into ``nbv bench``.

``integrator`` suite: depth images of a 3DT world are rendered first (not timed), then fused one
by one into a :class:`~nbv_prob_cnn.perception.TsdfIntegrator` over the 3DT box; the ternary
extraction (what the ``integrator`` node does before each published grid) is timed separately.

``fusion`` suite (:func:`fusion_suite`): dense against sparse fusion side by side in one run, on
the 3DT box and on the shared real recording (7-Scenes kitchen, room-sized): each case in a fresh
process (its peak RSS is its own), the frames read from the PNGs as they are fused (only
``integrate`` is timed), the labels of each mode compared cell by cell with dense fusion over the
same box.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from nbv_prob_cnn.perception.tsdf import DEFAULT_TRUNC_VOXELS

__all__ = ["SHARED_RECORDING", "benchmark_poses", "fusion_suite", "integrator_benchmark", "tsdf_quality"]

#: The real recording of the fusion suite (beside the checkout, never inside it: ../shared/data).
SHARED_RECORDING = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd" / "7scenes_redkitchen"


def benchmark_poses(
    frames: int, table_height_m: float, centre_xy=(0.742, 0.742), radius: float = 0.55
) -> list[np.ndarray]:
    """``world_from_optical`` poses on a ring around the table of the 3DT box, 0.40 / 0.57 m above
    the table top (alternating), looking at a point 5 cm above the table centre."""
    from nbv_prob_cnn.basics.camera import look_rotation

    target = np.array([centre_xy[0], centre_xy[1], table_height_m + 0.05])
    poses = []
    for i in range(frames):
        angle = 2.0 * math.pi * i / frames
        position = np.array(
            [
                centre_xy[0] + radius * math.cos(angle),
                centre_xy[1] + radius * math.sin(angle),
                table_height_m + (0.40, 0.57)[i % 2],
            ]
        )
        pose = np.eye(4)
        pose[:3, :3] = look_rotation(target - position)
        pose[:3, 3] = position
        poses.append(pose)
    return poses


def integrator_benchmark(
    frames: int = 60, width: int = 640, height: int = 480, seed: int = 1000, extractions: int = 5
) -> str:
    """Frames per second of :class:`TsdfIntegrator` at ``width``×``height`` on the 3DT box, as a
    markdown table (mean, median and 95th percentile per frame; ternary extraction time).

    Raises:
        ValueError: ``frames`` or ``extractions`` < 1.
    """
    if frames < 1 or extractions < 1:
        raise ValueError(f"frames and extractions must be positive, got {frames} and {extractions}")
    from nbv_prob_cnn.perception import DepthCamera, Intrinsics, TsdfIntegrator
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    camera = DepthCamera(world.triangle_meshes(), Intrinsics.from_hfov(width, height, 60.0))
    poses = benchmark_poses(frames, float(world.table["height_m"]))
    t0 = time.perf_counter()
    depths = [camera.render(pose) for pose in poses]
    render_s = (time.perf_counter() - t0) / frames
    valid = float(np.mean([np.mean(d > 0) for d in depths]))

    integrator = TsdfIntegrator()  # the 3DT box: 128 x 128 x 96 cells of 1.16 cm
    integrator.integrate(depths[0], camera.intrinsics, poses[0])  # warm-up (allocation, first-call costs)
    integrator.reset()
    per_frame = []
    for depth, pose in zip(depths, poses, strict=True):
        t = time.perf_counter()
        integrator.integrate(depth, camera.intrinsics, pose)
        per_frame.append(time.perf_counter() - t)
    extraction = []
    for _ in range(extractions):
        t = time.perf_counter()
        grid = integrator.ternary()
        extraction.append(time.perf_counter() - t)
    per_frame_ms = 1000.0 * np.asarray(per_frame)
    unknown = float(np.mean(grid == -1))

    rows = [
        ("frames", f"{frames} ({width}×{height}, {valid:.0%} pixels with a return)"),
        ("grid", f"{integrator.shape} cells, voxel {integrator.voxel_size} m, device {integrator.device}"),
        ("integration: frames/s (mean)", f"{1000.0 / per_frame_ms.mean():.1f}"),
        ("integration: ms/frame mean / median / p95", _triple(per_frame_ms)),
        ("ternary extraction: ms mean / median / p95", _triple(1000.0 * np.asarray(extraction))),
        ("rendering (not in the above): ms/frame", f"{1000.0 * render_s:.1f}"),
        ("unknown fraction after all frames", f"{unknown:.3f}"),
        ("CPU cores", str(os.cpu_count())),
    ]
    lines = [f"| TSDF integrator (3DT world seed {seed}) | value |", "|---|---|"]
    lines += [f"| {name} | {value} |" for name, value in rows]
    return "\n".join(lines)


def _triple(ms: np.ndarray) -> str:
    return f"{ms.mean():.1f} / {np.median(ms):.1f} / {np.percentile(ms, 95):.1f}"


def tsdf_quality(
    seed: int = 1000, views: int = 8, width: int = 640, height: int = 480, noise: str = "ideal", noise_seed: int = 0
) -> dict[str, float]:
    """How well the integrated grid of a generated 3DT world matches its ground truth.

    ``noise`` names a :mod:`nbv_prob_cnn.sensing.sensor_noise` preset for the rendered depth (the
    *seen* surface cells always come from the exact depth, so the presets are compared on the
    same reference).

    Depth frames from ``views`` poses around the table (:func:`benchmark_poses`) are fused; a
    ground-truth surface cell counts as *seen* when a depth pixel back-projects into it.

    Returns:
        ``empty_precision`` (cells labelled empty that are empty in the ground truth),
        ``surface_recall`` (seen ground-truth occupied cells labelled occupied),
        ``occupied_precision``, ``observed_fraction`` and the cell counts behind them.
    """
    from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
    from nbv_prob_cnn.perception import DepthCamera, Intrinsics, TsdfIntegrator
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    intrinsics = Intrinsics.from_hfov(width, height, 60.0)
    from nbv_prob_cnn.sensing.sensor_noise import sensor_noise

    camera = DepthCamera(world.triangle_meshes(), intrinsics)
    noisy_camera = DepthCamera(world.triangle_meshes(), intrinsics, noise=sensor_noise(noise), noise_seed=noise_seed)
    origin = np.asarray(world.origin, dtype=np.float64)
    shape = np.array(world.shape)
    nx, ny, nz = world.shape
    integrator = TsdfIntegrator(origin, (nx, ny, nz), world.resolution)
    seen = np.zeros(world.shape, dtype=bool)
    for pose in benchmark_poses(views, float(world.table["height_m"])):
        depth = camera.render(pose)
        integrator.integrate(noisy_camera.render(pose), intrinsics, pose)
        points = intrinsics.backproject(depth) @ pose[:3, :3].T + pose[:3, 3]
        ijk = np.floor((points - origin) / world.resolution).astype(int)
        seen[tuple(ijk[np.all((ijk >= 0) & (ijk < shape), axis=1)].T)] = True
    grid, truth = integrator.ternary(), world.ground_truth.astype(bool)
    empty, occupied, surface = grid == EMPTY, grid == OCCUPIED, seen & truth
    return {
        "empty_precision": float(1.0 - truth[empty].mean()),
        "surface_recall": float(occupied[surface].mean()),
        "occupied_precision": float(truth[occupied].mean()),
        "observed_fraction": float(np.mean(grid != UNKNOWN)),
        "empty_cells": int(empty.sum()),
        "seen_surface_cells": int(surface.sum()),
    }


# ------------------------------------------------------------------------------- fusion suite
@dataclass
class FusionCase:
    """One fusion run of the suite: where the frames come from, the cell, the mode and the box."""

    scene: str  # "3dt" (rendered) or a recording folder
    voxel_m: float
    fusion: str  # "dense" or "sparse"
    origin: tuple[float, float, float]  # corner of cell 0 (an open grid: a corner of its cell lattice)
    shape: tuple[int, int, int] | None  # None: an open grid (nbv integrate --bounds auto)
    depth_max: float
    frames: int


@dataclass
class FusionResult:
    case: FusionCase
    frames: int
    seconds: list[float]  # integrate() per frame
    rss_before_mb: float  # peak RSS before the integrator was made (imports, frames of 3dt)
    peak_rss_mb: float
    grid_path: str
    grid_origin: tuple[float, ...]
    grid_shape: tuple[int, int, int]
    blocks: int  # allocated at the end
    block_resolution: int


def recording_frames(folder: str, limit: int):
    """``(depth metres, intrinsics, pose)`` of a 7-Scenes folder, z up (minus gravity), read lazily."""
    from nbv_prob_cnn.perception.recordings import depth_mm, read_7scenes, read_depth_png, up_rotation

    recording = read_7scenes(folder)
    turn = np.eye(4) if recording.gravity is None else up_rotation(-recording.gravity)
    for frame in recording.frames[:limit]:
        pixels = read_depth_png(frame.depth_path, recording.intrinsics)
        assert pixels is not None
        yield depth_mm(recording, pixels).astype(np.float32) / 1000.0, recording.intrinsics, turn @ frame.pose


def _rendered_frames(limit: int, seed: int = 1000):
    from nbv_prob_cnn.perception import DepthCamera, Intrinsics
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    camera = DepthCamera(world.triangle_meshes(), Intrinsics.from_hfov(640, 480, 60.0))
    poses = benchmark_poses(limit, float(world.table["height_m"]))
    return [(camera.render(pose), camera.intrinsics, pose) for pose in poses]


def _run_fusion_case(case: FusionCase, out_dir: str) -> FusionResult:
    """One case, in its own process (peak RSS is the process's)."""
    from nbv_prob_cnn.basics.peak_memory import peak_rss_mb
    from nbv_prob_cnn.perception import TsdfIntegrator

    frames = _rendered_frames(case.frames) if case.scene == "3dt" else recording_frames(case.scene, case.frames)
    rss_before = peak_rss_mb()
    integrator = TsdfIntegrator(np.asarray(case.origin), case.shape, case.voxel_m, fusion=case.fusion)
    seconds = []
    n = 0
    for depth, intrinsics, pose in frames:
        t0 = time.perf_counter()
        integrator.integrate(depth, intrinsics, pose, depth_max=case.depth_max)
        seconds.append(time.perf_counter() - t0)
        n += 1
    path = str(Path(out_dir) / f"{len(os.listdir(out_dir))}.npy")
    grid = integrator.ternary()
    np.save(path, grid)
    origin_out, shape_out = integrator.grid_box()
    return FusionResult(
        case, n, seconds, rss_before, peak_rss_mb(), path, tuple(float(v) for v in origin_out), shape_out,
        integrator.allocated_blocks, integrator.block_resolution,
    )  # fmt: skip


def recording_box(folder: str | Path, voxel_m: float, margin_m: float, depth_max: float) -> tuple:
    """``(origin, shape)`` of the box of every return (within ``depth_max``) and camera position of a
    7-Scenes folder (z up), grown by ``margin_m``; the origin on the ``voxel_m`` lattice through 0."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for depth, intrinsics, pose in recording_frames(str(folder), 10**9):
        metres = np.where(depth <= depth_max, depth, 0.0)
        points = intrinsics.backproject(metres) @ pose[:3, :3].T + pose[:3, 3]
        points = np.vstack([points, pose[:3, 3]])
        lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    first = np.floor((lo - margin_m) / voxel_m)
    shape = tuple(int(v) for v in np.ceil((hi + margin_m) / voxel_m) - first)
    return tuple(float(v) for v in first * voxel_m), shape


def fusion_suite(
    recording: str | Path | None = None,
    voxels: tuple[float, ...] = (0.02, 0.0116),
    frames: int = 200,
    depth_max: float = 4.0,
    three_dt_frames: int = 60,
) -> str:
    """Dense and sparse fusion side by side (markdown): the 3DT box, then the recording at each cell
    size (dense and sparse over the box of its returns, sparse with ``--bounds auto``). Each case runs
    in a fresh process; the recording's cases are skipped, with the reason, when it is absent
    (``three_dt_frames=0``: no 3DT cases).
    """
    folder = Path(recording) if recording is not None else SHARED_RECORDING
    cases = [
        FusionCase("3dt", DEFAULT_3DT_VOXEL, mode, (0.0, 0.0, 0.0), DEFAULT_3DT_SHAPE, 3.0, three_dt_frames)
        for mode in ("dense", "sparse")
        if three_dt_frames > 0
    ]
    notes = []
    if folder.is_dir():
        for voxel in voxels:
            # the truncation band lies behind the returns: a margin of it and one cell more
            origin, shape = recording_box(folder, voxel, (DEFAULT_TRUNC_VOXELS + 1) * voxel, depth_max)
            for mode, case_shape in (("dense", shape), ("sparse", shape), ("sparse", None)):
                cases.append(FusionCase(str(folder), voxel, mode, origin, case_shape, depth_max, frames))
    else:
        notes.append(f"recording cases skipped: the shared recording is absent ({folder})")
    rows = []
    with tempfile.TemporaryDirectory(prefix="nbv_fusion_bench_") as out_dir:
        results = []
        for case in cases:
            with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
                results.append(pool.submit(_run_fusion_case, case, out_dir).result())
        for result in results:
            rows.append(_fusion_row(result, results))
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    header = [
        (
            "| scene | cell | mode | box | frames | frames/s (mean) | ms/frame median / p95 | peak RSS | RSS added "
            "| blocks | cells differing from dense |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    footer = [
        "",
        (
            f"{os.cpu_count()} CPU cores, load average at the end {load}; returns beyond {depth_max} m ignored on "
            f"the recording (3 m on the 3DT box); RSS added = peak RSS - peak RSS before the integrator existed "
            "(imports; the 3DT frames are rendered before it)."
        ),
        *notes,
    ]
    return "\n".join(header + rows + footer)


DEFAULT_3DT_VOXEL = 0.0116
DEFAULT_3DT_SHAPE = (128, 128, 96)


def _fusion_row(result: FusionResult, results: list[FusionResult]) -> str:
    case = result.case
    ms = 1000.0 * np.asarray(result.seconds)
    scene = "3DT box (rendered)" if case.scene == "3dt" else Path(case.scene).name
    box = ("auto " if case.shape is None else "") + " x ".join(str(s) for s in result.grid_shape)
    cells = math.prod(result.grid_shape)
    agreement = "-"
    if case.fusion == "sparse":
        dense = [
            r for r in results
            if r.case.fusion == "dense" and r.case.scene == case.scene and r.case.voxel_m == case.voxel_m
        ]  # fmt: skip
        if dense:
            agreement = _differing_cells(result, dense[0])
    return (
        f"| {scene} | {case.voxel_m * 100:g} cm | {case.fusion} | {box} ({cells / 1e6:.1f} M cells) | {result.frames} "
        f"| {1000.0 / ms.mean():.1f} | {np.median(ms):.1f} / {np.percentile(ms, 95):.1f} | "
        f"{result.peak_rss_mb:.0f} MB | {result.peak_rss_mb - result.rss_before_mb:.0f} MB | "
        f"{result.blocks} of {result.block_resolution}³ | "
        f"{agreement} |"
    )


def _differing_cells(sparse: FusionResult, dense: FusionResult) -> str:
    """Cells whose label differs from dense fusion's over the same box; an open grid (same lattice)
    is compared on its window of the box, and every cell of the box outside it must be unknown."""
    reference, grid = np.load(dense.grid_path), np.load(sparse.grid_path)
    if sparse.case.shape is not None:
        return str(int(np.count_nonzero(reference != grid)))
    offset = np.rint((np.asarray(sparse.grid_origin) - np.asarray(dense.grid_origin)) / dense.case.voxel_m).astype(int)
    end = offset + np.asarray(grid.shape)
    if np.any(offset < 0) or np.any(end > np.asarray(reference.shape)):
        return f"open grid reaches beyond the box ({grid.shape} at {offset.tolist()})"
    window = tuple(slice(int(a), int(b)) for a, b in zip(offset, end, strict=True))
    differing = int(np.count_nonzero(reference[window] != grid))
    outside = reference.copy()
    outside[window] = -1
    return f"{differing + int(np.count_nonzero(outside != -1))} (its window of the box)"
