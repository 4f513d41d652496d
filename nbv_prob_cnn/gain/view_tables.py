"""Host-side tables of the OpenCL ``view_gain`` kernel: the view -> rays membership as compressed
rows, per work-group first samples and bit sets of the views and rays to march, and the views a
coarse-to-fine search still has to evaluate."""

from __future__ import annotations

import numpy as np


def view_table(membership: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``(R, V)`` 0/1 ray-in-view matrix as compressed rows per view: ``start`` ``(V + 1,)``
    and ``rays`` (ascending ray indices of view ``w`` in ``rays[start[w]:start[w + 1]]``)."""
    member = np.asarray(membership) != 0
    counts = member.sum(axis=0)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    rays = np.nonzero(member.T)[1].astype(np.int32)
    return start, rays


def group_first_samples(padded: np.ndarray, origin_index: np.ndarray, group: int) -> np.ndarray:
    """Per block of ``group`` consecutive origins, the first sample ``t`` worth reading on any of
    their rays: the smallest Chebyshev distance ``d`` from the block's origins to a non-empty
    cell (samples ``0 .. d - 1`` of every ray are within ``d - 1`` cells, hence empty). One
    start per work-group keeps the work-items' loops in step (vectorizable)."""
    values = padded.reshape(-1)[origin_index]
    distance = np.where(values <= -2.0, -1.0 - values, 0.0).astype(np.int32)
    padding = -distance.size % group
    distance = np.concatenate([distance, np.zeros(padding, dtype=np.int32)]) if padding else distance
    return np.ascontiguousarray(distance.reshape(-1, group).min(axis=1), dtype=np.int32)


def bit_words(flags: np.ndarray) -> np.ndarray:
    """``(N, K)`` booleans as the kernel's bit sets: ``(N, ceil(K / 32))`` uint32, item ``k``
    in bit ``k % 32`` of word ``k // 32``."""
    flags = np.asarray(flags, dtype=bool)
    padded = np.zeros((flags.shape[0], -(-flags.shape[1] // 32) * 32), dtype=bool)
    padded[:, : flags.shape[1]] = flags
    return np.ascontiguousarray(np.packbits(padded, axis=1, bitorder="little")).view("<u4").astype(np.uint32)


def group_sets(view_sets: np.ndarray, membership: np.ndarray, group: int = 1) -> np.ndarray:
    """The kernel's per-work-group rows for ``(N, V)`` per-origin view sets: per block of
    ``group`` consecutive origins the union of their views, then the union of those views'
    rays (``membership``), each as :func:`bit_words` words."""
    padding = -view_sets.shape[0] % group
    rows = np.concatenate([view_sets, np.zeros((padding, view_sets.shape[1]), dtype=bool)]).astype(bool)
    unique, row = unique_rows(np.asarray(rows.reshape(-1, group, rows.shape[1]).any(axis=1)))
    view_rays = bit_words(np.asarray(membership).T != 0)  # (V, ray words); OR, not a BLAS product:
    rays = np.bitwise_or.reduce(np.where(unique[:, :, None], view_rays, np.uint32(0)), axis=1)  # its threads spin
    return np.ascontiguousarray(np.concatenate([bit_words(unique), rays.astype(np.uint32)], axis=1)[row])


def unique_rows(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of an ``(N, K)`` boolean array and per row its index among them (a
    1-D sort of 64-bit keys when ``K <= 64``, much faster than ``np.unique(axis=0)``)."""
    words = bit_words(flags)
    if words.shape[1] <= 2:
        key = words[:, 0].astype(np.uint64)
        if words.shape[1] == 2:
            key |= words[:, 1].astype(np.uint64) << np.uint64(32)
        _, first, row = np.unique(key, return_index=True, return_inverse=True)
    else:
        _, first, row = np.unique(words, axis=0, return_index=True, return_inverse=True)
    return np.asarray(flags, dtype=bool)[first], row.ravel()


def pad_to(values: np.ndarray, multiple: int) -> np.ndarray:
    """``values`` (1-D) with its last item repeated up to a length multiple of ``multiple``."""
    padding = -values.size % multiple
    return np.ascontiguousarray(np.concatenate([values, np.repeat(values[-1:], padding)]) if padding else values)


def reaching_views(view_bound: np.ndarray, block_of: np.ndarray, best: float) -> tuple[np.ndarray, np.ndarray]:
    """The views worth evaluating from origins of blocks ``block_of``: those whose block bound
    reaches ``best`` (no other view can reach or beat the best gain found). Returns per origin a
    view-set index and the distinct view sets ``(P, V)`` bool."""
    blocks, block_row = np.unique(block_of, return_inverse=True)
    reach = view_bound[blocks] >= np.float32(best)
    sets, set_row = unique_rows(reach)
    return set_row[block_row.ravel()], sets
