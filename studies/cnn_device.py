"""The completion CNN of one planning step on another device (issue #35: can the scale targets be met
with a GPU for the CNN?): the product's ``complete()`` on 3DT's 128 × 128 × 96 corner and on the whole
grid of a saved state, per device, best of ``--repeats``; the outputs of each device against the first.

Run where a GPU is: ``nbv study cnn_device --state state.npy --devices cuda cpu --out studies/results/cnn_device``
(the state: ``np.save`` of :func:`~nbv_prob_cnn.bench.scale.scale_state` for ``(256, 256, 192)``, seed 1000;
made here when ``--state`` is absent).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

#: The corner of the grid timed first: 3DT's own size.
CORNER = (128, 128, 96)


def time_device(state: np.ndarray, device: str, repeats: int) -> tuple[list[float], np.ndarray, float]:
    """Seconds of each ``complete`` of ``state`` on ``device`` (after a warm-up on 3DT's corner), the last
    map and the peak GPU memory in MiB (0 on a CPU)."""
    import torch

    from nbv_prob_cnn.completion import complete

    corner = np.ascontiguousarray(state[tuple(slice(0, n) for n in CORNER)])  # (or less)
    complete(corner, dataset="3dt", device=device)  # weights, kernels
    cuda = device.startswith("cuda")
    times, prob = [], None
    for _ in range(repeats):
        if cuda:
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
        start = time.perf_counter()
        prob = complete(state, dataset="3dt", device=device)  # returns host memory: synchronised
        times.append(time.perf_counter() - start)
    assert prob is not None
    return times, prob, (torch.cuda.max_memory_allocated() / 2**20 if cuda else 0.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--state", type=Path, help="a saved ternary grid (.npy); default: the scale bench's 256^2x192")
    parser.add_argument("--devices", nargs="+", default=["cuda", "cpu"], help="torch devices, the first the reference")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per grid and device (best reported)")
    parser.add_argument("--out", type=Path, default=Path("studies/results/cnn_device"), help="its JSON's folder")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        raise ValueError(f"--repeats: expected at least 1, got {args.repeats}")
    if args.state is not None:
        state = np.load(args.state)
    else:
        from nbv_prob_cnn.bench.scale import scale_state

        state = scale_state((256, 256, 192), 1000)
    corner = np.ascontiguousarray(state[tuple(slice(0, n) for n in CORNER)])  # the whole state if smaller
    grids = {"x".join(map(str, corner.shape)): corner, "x".join(map(str, state.shape)): state}
    rows: list[dict] = []
    reference: dict[str, np.ndarray] = {}
    for device in args.devices:
        for name, grid in grids.items():
            times, prob, peak = time_device(grid, device, args.repeats)
            row = {"device": device, "grid": name, "cells": int(grid.size), "seconds": times, "best_s": min(times),
                   "peak_gpu_mib": peak}  # fmt: skip
            if name in reference:
                row["max_abs_diff_vs_" + args.devices[0]] = float(np.abs(prob - reference[name]).max())
            else:
                reference[name] = prob
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cnn_device.json").write_text(json.dumps(rows, indent=1) + "\n")
    return 0
