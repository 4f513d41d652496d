"""Throughput of the TSDF integrator (a benchmark, not a test): wired into ``nbv bench``.

Depth images of a 3DT world are rendered first (not timed), then fused one by one into a
:class:`~nbv_prob_cnn.perception.TsdfIntegrator` over the 3DT box; the ternary extraction (what
the ``integrator`` node does before each published grid) is timed separately.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

__all__ = ["benchmark_poses", "integrator_benchmark", "tsdf_quality"]


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


if __name__ == "__main__":
    print(integrator_benchmark())


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
