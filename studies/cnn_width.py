"""What a narrower completion CNN would buy on this CPU (issue #35: the scale targets' CNN share): the
forward pass of the paper's 3DT network (``n_conv`` 4, first block 16 channels) against the same network with
fewer channels, on 3DT's grid and the scale bench's 256 × 256 × 192, per width, best of ``--repeats``.

Untrained weights and a random ternary grid: dense convolutions cost the same whatever the values, so no
network is trained for this (how well a narrower one would complete is a separate question). Run with
``nbv study cnn_width --out studies/results/cnn_width``; CSV and PNG there.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

#: Grids timed: 3DT's and the scale bench's largest.
GRIDS = ((128, 128, 96), (256, 256, 192))
#: First-block widths timed (16: the paper's 3D network).
WIDTHS = (16, 12, 8, 4)
#: Conv blocks of the 3DT network (the paper's ``N_conv``).
N_CONV_3DT = 4


def time_width(state: np.ndarray, width: int, repeats: int, threads: int) -> float:
    """Best seconds of ``complete()`` on ``state`` with an untrained ``CompletionNet(3, 4, width)``."""
    import torch

    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.completion.model import CompletionNet

    torch.set_num_threads(threads)
    net = CompletionNet(3, N_CONV_3DT, width).eval()
    complete(np.ascontiguousarray(state[:32, :32, :32]), model=net)  # kernels chosen, memory touched
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        complete(state, model=net)
        best = min(best, time.perf_counter() - start)
    return best


def save_plot(rows: list[dict], path: Path) -> None:
    """Seconds against grid cells, one line per width."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for width in sorted({r["width"] for r in rows}, reverse=True):
        mine = [r for r in rows if r["width"] == width]
        label = f"{width} channels" + (" (the paper's)" if width == 16 else "")
        ax.plot([r["cells"] / 1e6 for r in mine], [r["seconds"] for r in mine], "o-", label=label)
    ax.set_xlabel("grid cells (millions)")
    ax.set_ylabel("CNN forward pass (s)")
    ax.set_title("3DT completion CNN by first-block width, this CPU")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--widths", type=int, nargs="+", default=list(WIDTHS), help="first-block channel counts")
    parser.add_argument("--grids", nargs="+", default=["x".join(map(str, g)) for g in GRIDS], help="e.g. 128x128x96")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs per grid and width (best reported)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--out", type=Path, default=Path("studies/results/cnn_width"), help="CSV and PNG folder")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.threads < 1 or min(args.widths) < 1:
        raise ValueError("--repeats, --threads and --widths: expected positive integers")
    try:
        shapes = [tuple(int(v) for v in g.split("x")) for g in args.grids]
    except ValueError:
        raise ValueError(f"--grids: expected sizes like 128x128x96, got {args.grids}") from None
    if any(len(s) != 3 or min(s) < 1 for s in shapes):
        raise ValueError(f"--grids: expected three positive sizes each, got {args.grids}")
    rng = np.random.default_rng(0)
    rows: list[dict] = []
    for shape in shapes:
        state = (rng.integers(0, 3, size=shape) - 1).astype(np.int8)
        paper_s = None
        for width in args.widths:
            seconds = time_width(state, width, args.repeats, args.threads)
            paper_s = seconds if width == 16 else paper_s
            row = {"grid": "x".join(map(str, shape)), "cells": int(state.size), "width": width, "seconds": seconds,
                   "vs_paper": float("nan") if paper_s is None else seconds / paper_s}  # fmt: skip
            rows.append(row)
            print(f"{row['grid']}: {width} channels {seconds:.3f} s ({row['vs_paper']:.2f} of the paper's)", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "cnn_width.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    save_plot(rows, args.out / "cnn_width.png")
    print(f"wrote {args.out / 'cnn_width.csv'} and {args.out / 'cnn_width.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
