"""Boxes of grid cells: ``(lo, hi)`` per axis, ``lo`` inclusive, ``hi`` exclusive."""

from __future__ import annotations

#: A box of cells: ``(lo, hi)``, ``lo`` inclusive and ``hi`` exclusive per axis.
Region = tuple[tuple[int, ...], tuple[int, ...]]


def check_region(region: Region | None, shape: tuple[int, ...], name: str = "region") -> Region:
    """``region`` clipped to a grid of ``shape`` (None: the whole grid).

    Raises:
        ValueError: not a pair of per-axis bounds, or an empty box inside the grid.
    """
    if region is None:
        return (0,) * len(shape), tuple(int(s) for s in shape)
    try:
        lo, hi = (tuple(int(v) for v in bound) for bound in region)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected (lo, hi) cell bounds per axis, got {region!r}") from None
    if len(lo) != len(shape) or len(hi) != len(shape):
        raise ValueError(f"{name}: expected {len(shape)} bounds per side, got {region!r}")
    lo = tuple(max(0, v) for v in lo)
    hi = tuple(min(s, v) for s, v in zip(shape, hi, strict=True))
    if any(a >= b for a, b in zip(lo, hi, strict=True)):
        raise ValueError(f"{name}: {region!r} holds no cell of the grid of shape {shape}")
    return lo, hi


def region_slices(region: Region) -> tuple[slice, ...]:
    """The index of a region's cells in a grid array."""
    return tuple(slice(a, b) for a, b in zip(*region, strict=True))
