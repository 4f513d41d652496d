"""The completion CNN on tiles and over a region only (docs/performance.md#scale).

**Receptive field.** :class:`~nbv_prob_cnn.completion.model.CompletionNet` with the completion
head (no removed or extra deconv blocks) is fully convolutional; an output cell depends on the input
cells within a radius ``R`` along each axis. :func:`receptive_interval` computes the input interval of
an output cell from the layers themselves (kernel sizes, strides, paddings of every conv and deconv,
the skip connections included), :func:`receptive_radius` the largest distance over the network's
period ``2**n_conv``. By hand: a conv block ``i`` (conv k3 s1 p1, conv k3 s2 p1) maps an interval
``[a, b]`` of its output to ``[2a - 2, 2b + 2]`` of its input, so a cell of the level-``L`` features
reads ``±(2**(L+1) - 2)`` input cells around ``2**L j``; a deconv (k3 s2 p1 op1) reads the cells
``floor(o/2) .. ceil(o/2)`` of the coarser level; the deepest path (``L = n_conv``) gives
``R = (2**n_conv - 1) + 2**(n_conv+1) - 2 = 3 * 2**n_conv - 3``. The shipped 3DT CNN
(``n_conv = 4``): **R = 45 cells** (0.52 m at 1.16 cm); 3DU (``n_conv = 3``): 21; 2D (``n_conv = 5``): 93.

**Tiles.** :func:`complete_region` runs the network on tiles: a tile's *core* is a box of the
region, its *window* the core grown by the halo :func:`halo_cells` (``R`` rounded up to a multiple
of ``2**n_conv``: 48 on 3DT), clipped to the grid. Every core (and so every window) starts on a
multiple of ``2**n_conv``, the network's total stride: the stride-2 convolutions of a window then
sample the same cells as on the whole grid, and a window that ends at the grid's end is padded
exactly as the whole grid is. The cells a core's output depends on lie inside its window, so the
stitched cores equal whole-grid inference up to float rounding (measured below 1e-5 on 3DT; the tests
check 1e-4). A core without unknown cells needs no network (``P`` is 0 or 1 there). A region whose
window fits ``max_window_cells`` is one tile: the same computation as
:func:`~nbv_prob_cnn.completion.inference.complete` on that window (on a whole grid, identical).
Tiles bound the memory of a pass (about 143 bytes per window cell on a CPU) at the price of
recomputing the halos.

**Windows.** :func:`complete_window` is the approximate, local alternative: the network sees only
a window of the grid (its border acts as the grid's border) and unknown cells outside it get the
constant prior ``p0`` of Prob. IG.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from math import prod
from typing import Any

import numpy as np
import torch

from nbv_prob_cnn.basics.grid import UNKNOWN, check_state, probability_with_constant
from nbv_prob_cnn.basics.region import Region, check_region, region_slices
from nbv_prob_cnn.completion.inference import complete, load_model, resolve_device
from nbv_prob_cnn.completion.model import CompletionNet

#: Default bound on the cells of one tile's window: 16 M cells, about 2.2 GB at the 143 bytes per cell
#: measured on a CPU (a 256×256×192 grid is one pass; tiles recompute their halos, 1.9× the cells there).
MAX_WINDOW_CELLS = 16_000_000
#: Most tiles per axis :func:`plan_tiles` considers.
MAX_SPLIT = 6


def _geometry(layer: Any) -> tuple[int, int, int]:
    """Kernel size, stride and padding of a (transposed) convolution along its first axis."""
    return int(layer.kernel_size[0]), int(layer.stride[0]), int(layer.padding[0])


def _conv_input(layer: Any, lo: int, hi: int) -> tuple[int, int]:
    """Input interval (along one axis) of the output interval ``[lo, hi]`` of a convolution."""
    k, s, p = _geometry(layer)
    return lo * s - p, hi * s - p + k - 1


def _deconv_input(layer: Any, lo: int, hi: int) -> tuple[int, int]:
    """Input interval of the output interval ``[lo, hi]`` of a transposed convolution (output
    ``o = i s - p + k'`` for kernel tap ``k'``)."""
    k, s, p = _geometry(layer)
    return -((k - 1 - lo - p) // s), (hi + p) // s


def _check_completion_net(model: CompletionNet) -> None:
    if model.head != "completion" or model.removed_deconv or model.extra_deconv:
        raise ValueError("model: tiled inference needs a completion network (no removed or extra deconv blocks)")


def receptive_interval(model: CompletionNet, position: int) -> tuple[int, int]:
    """The input cells ``[lo, hi]`` (one axis, unbounded grid) that output cell ``position`` depends on,
    from the layers of ``model`` (the skip connections included)."""
    _check_completion_net(model)

    def encoder_input(level: int, lo: int, hi: int) -> tuple[int, int]:
        for block in reversed(list(model.encoder)[:level]):
            for layer in reversed([m for m in block.children() if hasattr(m, "kernel_size")]):
                lo, hi = _conv_input(layer, lo, hi)
        return lo, hi

    def decoder_input(level: int, lo: int, hi: int) -> tuple[int, int]:
        """Input interval of the decoder's concatenation at ``level`` (level ``n_conv``: the bottleneck)."""
        skip = encoder_input(level, lo, hi)
        if level == model.n_conv:
            return skip
        deconv = next(iter(list(model.decoder)[level].children()))
        deeper = decoder_input(level + 1, *_deconv_input(deconv, lo, hi))
        return min(skip[0], deeper[0]), max(skip[1], deeper[1])

    return decoder_input(0, *_conv_input(model.final, position, position))


def receptive_radius(model: CompletionNet) -> int:
    """Largest distance (cells, along an axis) between an output cell and an input cell it depends on
    (3DT: 45)."""
    return max(
        max(position - lo, hi - position)
        for position in range(model.multiple)
        for lo, hi in [receptive_interval(model, position)]
    )


def halo_cells(model: CompletionNet) -> int:
    """The tiles' halo: :func:`receptive_radius` rounded up to a multiple of ``2**n_conv`` (3DT: 48)."""
    return -(-receptive_radius(model) // model.multiple) * model.multiple


@dataclass(frozen=True)
class Tile:
    """One pass of the network: the ``core`` it delivers and the ``window`` it reads."""

    core: Region
    window: Region

    def slices(self, which: str) -> tuple[slice, ...]:
        return region_slices(self.core if which == "core" else self.window)

    def core_in_window(self) -> tuple[slice, ...]:
        return tuple(
            slice(c - w, c - w + (h - c)) for c, h, w in zip(self.core[0], self.core[1], self.window[0], strict=True)
        )


def _axis_cores(lo: int, hi: int, count: int, multiple: int) -> list[tuple[int, int]]:
    """``count`` (or fewer) cores covering ``[lo, hi)``, starting on multiples of ``multiple``."""
    start = lo // multiple * multiple
    per_core = -(-(hi - start) // count)  # cells per core, rounded up
    size = -(-per_core // multiple) * multiple
    return [(max(lo, a), min(hi, a + size)) for a in range(start, hi, size)]


def plan_tiles(
    shape: tuple[int, ...], region: Region, multiple: int, halo: int, max_window_cells: int = MAX_WINDOW_CELLS
) -> list[Tile]:
    """Tiles whose cores cover ``region``: cores start on multiples of ``multiple``, windows are the
    cores grown by ``halo`` (clipped to the grid). Of the splits into up to :data:`MAX_SPLIT` tiles per
    axis whose windows hold at most ``max_window_cells`` cells each, the one that computes the fewest
    cells in all (none fits: the one with the smallest largest window)."""
    if halo % multiple:
        raise ValueError(f"halo: expected a multiple of {multiple}, got {halo}")
    lo, hi = region

    def windows(axis: int, count: int) -> list[tuple[tuple[int, int], tuple[int, int]]]:
        """(core, window) intervals along ``axis`` split into ``count`` cores."""
        return [
            ((a, b), (max(0, a // multiple * multiple - halo), min(shape[axis], b + halo)))
            for a, b in _axis_cores(lo[axis], hi[axis], count, multiple)
        ]

    # every split up to MAX_SPLIT tiles per axis; the fewest computed cells among those that fit
    # (windows are products of per-axis intervals: largest and total cells factor per axis)
    splits = [
        [windows(axis, count) for count in range(1, min(MAX_SPLIT, -(-(hi[axis] - lo[axis]) // multiple)) + 1)]
        for axis in range(len(shape))
    ]
    best: tuple[tuple[int, int], tuple[int, ...]] | None = None
    for choice in np.ndindex(*(len(s) for s in splits)):
        lengths = [[w[1] - w[0] for _, w in splits[axis][c]] for axis, c in enumerate(choice)]
        largest, total = prod(max(v) for v in lengths), prod(sum(v) for v in lengths)
        key = (0 if largest <= max_window_cells else largest, total)
        if best is None or key < best[0]:
            best = (key, choice)
    assert best is not None
    per_axis = [splits[axis][c] for axis, c in enumerate(best[1])]
    tiles = []
    for index in np.ndindex(*(len(a) for a in per_axis)):
        parts = [per_axis[axis][i] for axis, i in enumerate(index)]
        core = tuple(c[0] for c, _ in parts), tuple(c[1] for c, _ in parts)
        window = tuple(w[0] for _, w in parts), tuple(w[1] for _, w in parts)
        tiles.append(Tile(core, window))
    return tiles


def _resolve(model: CompletionNet | str | None, dataset: str | None, device) -> CompletionNet:
    if isinstance(model, CompletionNet):
        net = model
    else:
        if model is None and dataset is None:
            raise ValueError("dataset: required without a model ('2d', '3du' or '3dt')")
        net = load_model(model, dataset, resolve_device(device))
    _check_completion_net(net)
    return net


def complete_region(
    state: np.ndarray,
    region: Region | None = None,
    model: CompletionNet | str | None = None,
    dataset: str | None = None,
    fill: float = 0.15,
    device: str | torch.device | None = None,
    max_window_cells: int = MAX_WINDOW_CELLS,
    halo: int | None = None,
    precision: str = "float32",
) -> np.ndarray:
    """The probabilistic map ``P`` of ``state`` inside ``region``, by tiles (see the module doc):
    equal to :func:`~nbv_prob_cnn.completion.inference.complete` there up to float rounding.

    Args:
        state: ternary grid.
        region: ``(lo, hi)`` cell box (None: the whole grid); clipped to the grid.
        model, dataset, device: as :func:`~nbv_prob_cnn.completion.inference.complete`.
        fill: the probability of unknown cells outside ``region`` (the planners pass the data set's
            ``p0``; their rays never read those cells).
        max_window_cells: the most cells one pass of the network reads.
        halo: cells of context around each tile's core, a multiple of ``2**n_conv`` (default
            :func:`halo_cells`; a smaller one gives other numbers than the whole grid).
        precision: the forward pass's arithmetic (:data:`~nbv_prob_cnn.basics.modes.CNN_PRECISIONS`).

    Returns:
        ``float32`` array of the shape of ``state``.
    """
    state = check_state(state)
    net = _resolve(model, dataset, device)
    if net.dims != state.ndim:
        raise ValueError(f"state: a {state.ndim}D grid does not fit a {net.dims}D completion model")
    if not 0.0 <= fill <= 1.0:
        raise ValueError(f"fill: expected a probability in [0, 1], got {fill!r}")
    if max_window_cells < 1:
        raise ValueError(f"max_window_cells: expected a positive count, got {max_window_cells!r}")
    box = check_region(region, state.shape)
    halo = halo_cells(net) if halo is None else halo
    tiles = plan_tiles(state.shape, box, net.multiple, halo, max_window_cells)
    whole = check_region(None, state.shape)
    if len(tiles) == 1 and tiles[0].core == tiles[0].window == whole:
        return complete(state, model=net, device=device, precision=precision)  # one pass over the grid: no copies
    out = probability_with_constant(state, fill)
    for tile in tiles:
        core = tile.slices("core")
        if not np.any(state[core] == UNKNOWN):
            continue  # P is 0 / 1 on known cells: no network needed
        window = complete(
            np.ascontiguousarray(state[tile.slices("window")]), model=net, device=device, precision=precision
        )
        out[core] = window[tile.core_in_window()]
    return out


def complete_window(
    state: np.ndarray,
    window: Region,
    p0: float,
    model: CompletionNet | str | None = None,
    dataset: str | None = None,
    device: str | torch.device | None = None,
    max_window_cells: int = MAX_WINDOW_CELLS,
    completion: Callable[[np.ndarray, tuple[int, ...]], np.ndarray] | None = None,
    precision: str = "float32",
) -> np.ndarray:
    """``P`` with the network run on ``window`` alone (its border acts as the grid's border) and
    ``p0`` on the unknown cells outside it (Prob. IG's constant prior): a local completion whose
    cost follows the window, not the grid. ``completion(window_state, corner)``: the window's map
    from elsewhere (e.g. a completion service; ``corner``: the window's first cell), instead of the
    network here (whose arithmetic is ``precision``).

    Returns:
        ``float32`` array of the shape of ``state``.
    """
    state = check_state(state)
    crop = region_slices(check_region(window, state.shape, "window"))
    out = probability_with_constant(state, p0)
    inner = np.ascontiguousarray(state[crop])
    if completion is None:
        out[crop] = complete_region(inner, None, model, dataset, p0, device, max_window_cells, precision=precision)
    else:
        window_map = np.asarray(completion(inner, tuple(int(v) for v in window[0])), dtype=np.float32)
        if window_map.shape != inner.shape:
            raise ValueError(f"completion: returned a map of shape {window_map.shape} for a window of {inner.shape}")
        out[crop] = window_map
    return out
