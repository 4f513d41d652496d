"""The City-CNN baselines (paper §III-D and §IV): inputs, training targets, output masks and
decoding, for the networks built on the completion encoder-decoder
(:class:`~nbv_prob_cnn.completion.model.CompletionNet`), and the three planners
(``flat_city_cnn``, ``b_city_cnn``, ``d_city_cnn``): the network predicts view (or ray) gains from
``E`` and ``F``; the best predicted view wins. They read their trained weights
``nbv_prob_cnn/weights/<dataset>_<method>.pt`` (missing weights: an error naming the ``nbv train``
command). The sensor they were trained for is the data set's; the context's sensor and ``n_rays``
overrides do not apply to them.

* Input: 2 channels, ``E`` (known empty) and ``F`` (frontier).
* Output lattice: one cell per ``stride`` cells per axis, ``stride = spec.city_output_stride``
  (1, or 8 on 3DT: three deconv blocks removed, as in the paper); lattice cell ``o`` stands for
  the grid cell ``o * stride``. Outputs are multiplied by the empty mask of those cells.
* ``flat_city_cnn``: ``N_views`` channels, the gain of each candidate view.
* ``b_city_cnn``: 2 (2D) / 4 (3D) channels in [−1, 1]: the best view's gain times its direction
  ``(cos yaw, sin yaw)`` (2D) or its quaternion (3D, ``w >= 0``).
* ``d_city_cnn``: one channel at ``N_rays``× the lattice resolution (``N_rays = spec.city_n_rays``):
  composite cells whose boundary sub-cells hold the gain of the matching ray (same order as
  :func:`~nbv_prob_cnn.gain.ray_directions`), the central sub-cells masked to 0.

Targets are the gains of the omniscient method (docs/method.md#probabilistic-ray-casting-gain with ``P = D``
in unknown cells): for a
ray, the unknown cells it would observe against the ground truth (up to and including the first
occupied one), each weighted ``t^ν`` and normalised by ``Σ t^ν``; for a view, the sum over its
rays. View gains are divided by the largest number of rays in a view so that every target lies
in [0, 1] (a constant factor: rankings are unchanged). Decisions: B-City-CNN's continuous
direction is snapped to the nearest candidate orientation (the targets are built from that set);
the 3DT lattice (8× stride) follows the paper's three removed deconv blocks.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.basics.grid import (
    check_ground_truth,
    check_state,
    frontier_mask,
    lattice_index,
    probability_from_truth,
)
from nbv_prob_cnn.completion.model import CompletionNet
from nbv_prob_cnn.gain import empty_origins, ray_directions, ray_gains, view_membership
from nbv_prob_cnn.planners.base import OriginFilter, PlanningContext, RankingPlanner, ViewChoice

CITY_METHODS = ("flat_city_cnn", "b_city_cnn", "d_city_cnn")


def _check_method(method: str) -> None:
    if method not in CITY_METHODS:
        raise ValueError(f"method: expected one of {CITY_METHODS}, got {method!r}")


@dataclass(frozen=True)
class CityGeometry:
    """Directions, views and lattice of one City-CNN variant on one data set."""

    method: str
    spec: DatasetSpec
    directions: np.ndarray  # (R, dims) rays whose gains the targets are made of
    membership: np.ndarray  # (R, V) 0/1
    stride: int

    @classmethod
    def of(cls, method: str, spec: DatasetSpec) -> CityGeometry:
        _check_method(method)
        n_rays = spec.city_n_rays if method == "d_city_cnn" else spec.n_rays
        directions = ray_directions(spec.dims, n_rays)
        member = view_membership(directions, orientations(spec.dims), spec.sensor.hfov_deg, spec.sensor.vfov_deg)
        return cls(method, spec, directions, member, spec.city_output_stride)

    @property
    def n_rays(self) -> int:
        return self.spec.city_n_rays if self.method == "d_city_cnn" else self.spec.n_rays

    @property
    def view_scale(self) -> float:
        """Largest number of rays in one view (view gains are divided by it)."""
        return float(self.membership.sum(axis=0).max())

    def origins(self, state: np.ndarray) -> np.ndarray:
        """Empty cells on the output lattice (grid indices)."""
        return empty_origins(state, self.stride)


def boundary_subcells(dims: int, n: int) -> np.ndarray:
    """``(R, dims)`` indices of the boundary sub-cells of an ``n``-per-side square/cube, in the
    order of :func:`~nbv_prob_cnn.gain.ray_directions` (ray ``h`` ↔ sub-cell ``h``)."""
    return np.array(
        [idx for idx in itertools.product(range(n), repeat=dims) if any(i in (0, n - 1) for i in idx)], dtype=np.int64
    )


def build_network(method: str, spec: DatasetSpec, first_channels: int | None = None) -> CompletionNet:
    """The encoder-decoder of a City-CNN variant on a data set."""
    _check_method(method)
    removed = int(round(math.log2(spec.city_output_stride)))
    if method == "flat_city_cnn":
        n_views = len(orientations(spec.dims))
        return CompletionNet(spec.dims, spec.n_conv, first_channels, n_views, "sigmoid", removed)
    if method == "b_city_cnn":
        return CompletionNet(spec.dims, spec.n_conv, first_channels, 2 if spec.dims == 2 else 4, "tanh", removed)
    extra = int(round(math.log2(spec.city_n_rays)))
    if 2**extra != spec.city_n_rays:
        raise ValueError(f"city_n_rays: D-City-CNN needs a power of two, got {spec.city_n_rays}")
    return CompletionNet(spec.dims, spec.n_conv, first_channels, 1, "sigmoid", removed, extra)


def encode_city_input(states: np.ndarray) -> torch.Tensor:
    """Ternary grids ``(B, *spatial)`` -> float input ``(B, 2, *spatial)``: channels E and F."""
    empty = np.stack([s == 0 for s in states])
    frontier = np.stack([frontier_mask(s) for s in states])
    return torch.as_tensor(np.stack([empty, frontier], axis=1), dtype=torch.float32)


def output_mask(geometry: CityGeometry, state: np.ndarray) -> np.ndarray:
    """``(*out_spatial)`` float32 mask of the network output: 1 at empty lattice cells (D-City:
    their boundary sub-cells), 0 elsewhere (and at the central sub-cells)."""
    s = geometry.stride
    return lattice_output_mask(geometry, (state == 0)[lattice_index(state.ndim, s)])


def lattice_output_mask(geometry: CityGeometry, empty_lattice: np.ndarray) -> np.ndarray:
    """:func:`output_mask` from the empty mask of the output lattice cells (``(*lattice)`` bool)."""
    empty = empty_lattice.astype(np.float32)
    if geometry.method != "d_city_cnn":
        return empty
    n = geometry.n_rays
    composite = np.zeros((n,) * empty.ndim, dtype=np.float32)
    composite[tuple(boundary_subcells(empty.ndim, n).T)] = 1.0
    return np.kron(empty, composite).astype(np.float32)


def omniscient_ray_gains(
    state: np.ndarray, truth: np.ndarray, geometry: CityGeometry, origins: np.ndarray, backend: str = "auto"
) -> np.ndarray:
    """``(N, R)`` gains of the rays from ``origins`` against the ground truth: the omniscient
    method's kernel call (``P = D`` in unknown cells)."""
    prob = probability_from_truth(state, truth)
    return ray_gains(state, prob, geometry.directions, geometry.spec.sensor.r_max, origins, backend)


def city_targets(
    method: str,
    state: np.ndarray,
    truth: np.ndarray,
    spec: DatasetSpec,
    box: tuple[slice, ...] | None = None,
    backend: str = "auto",
) -> np.ndarray:
    """Training target of a City-CNN variant: ``(C, *out_spatial)`` float32 (see module docs).

    Args:
        box: a crop of the grid (starts on the output lattice): targets of the lattice cells
            inside it only, their rays still cast through the whole grid.

    Raises:
        ValueError: bad grids, a ground truth of another shape or a box off the lattice.
    """
    state = check_state(state)
    truth = check_ground_truth(truth, state.shape, name="truth")
    geometry = CityGeometry.of(method, spec)
    box = box or tuple(slice(0, n) for n in state.shape)
    origins, local, lattice = lattice_origins_in_box(geometry, state, box)
    gains = omniscient_ray_gains(state, truth, geometry, origins, backend) if origins.size else None
    return assemble_city_target(method, spec, gains, local, lattice)


def lattice_origins_in_box(
    geometry: CityGeometry, state: np.ndarray, box: tuple[slice, ...]
) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """The empty lattice cells inside a crop ``box`` (starts on the lattice): their grid indices
    ``(N, dims)`` in ``np.argwhere`` order, their lattice cells inside the box ``(N, dims)`` and
    the box's lattice shape.

    Raises:
        ValueError: a box off the lattice.
    """
    s = geometry.stride
    start = np.array([b.start for b in box], dtype=np.int64)
    if np.any(start % s):
        raise ValueError(f"box: starts {start.tolist()} are not on the {s}-cell output lattice")
    lattice = tuple(-(-(b.stop - b.start) // s) for b in box)
    origins = geometry.origins(state)
    inside = np.all((origins >= start) & (origins < np.array([b.stop for b in box])), axis=1)
    origins = origins[inside]
    return origins, (origins - start) // s, lattice


def assemble_city_target(
    method: str, spec: DatasetSpec, gains: np.ndarray | None, local: np.ndarray, lattice: tuple[int, ...]
) -> np.ndarray:
    """The target ``(C, *lattice)`` of a City-CNN variant from the ray gains ``(N, R)`` of the
    lattice cells ``local`` (``(N, dims)``; ``gains`` None when there is none): ray-casting
    (:func:`omniscient_ray_gains`) and assembly are separate so that cached ray gains
    (:mod:`nbv_prob_cnn.completion.city_cache`) make the same targets."""
    geometry = CityGeometry.of(method, spec)
    dims = len(lattice)
    if gains is not None:
        gains = np.asarray(gains, dtype=np.float32)
        if gains.shape != (local.shape[0], geometry.directions.shape[0]):
            raise ValueError(
                f"gains: expected shape {(local.shape[0], geometry.directions.shape[0])}, got {gains.shape}"
            )
    if method == "d_city_cnn":
        n = geometry.n_rays
        target = np.zeros(tuple(size * n for size in lattice), dtype=np.float32)
        if gains is not None:
            sub = boundary_subcells(dims, n)  # (R, dims)
            index = local[:, None, :] * n + sub[None, :, :]  # (N, R, dims)
            target[tuple(index.reshape(-1, dims).T)] = gains.reshape(-1)
        return target[None]
    views = (gains @ geometry.membership) / geometry.view_scale if gains is not None else None
    cells = tuple(local.T)
    if method == "flat_city_cnn":
        target = np.zeros((geometry.membership.shape[1], *lattice), dtype=np.float32)
        if views is not None:
            target[(slice(None), *cells)] = views.T
        return target
    target = np.zeros((2 if dims == 2 else 4, *lattice), dtype=np.float32)
    if views is not None:
        best = np.argmax(views, axis=1)
        target[(slice(None), *cells)] = (views[np.arange(len(best)), best][:, None] * _view_vectors(spec)[best]).T
    return target


def _view_vectors(spec: DatasetSpec) -> np.ndarray:
    """B-City-CNN's unit vector of each candidate orientation: ``(cos, sin)`` of the yaw (2D) or
    the quaternion with ``w >= 0`` (3D)."""
    candidates = orientations(spec.dims)
    if spec.dims == 2:
        return np.stack([np.cos(candidates), np.sin(candidates)], axis=1)
    return np.where(candidates[:, 3:4] < 0, -candidates, candidates)


def decode_views(
    method: str, output: np.ndarray, state: np.ndarray, spec: DatasetSpec, origins: np.ndarray
) -> np.ndarray:
    """``(N, V)`` view gains at ``origins`` (lattice cells, grid indices) from a network output
    ``(C, *out_spatial)``; B-City-CNN gives its gain to the nearest candidate view only."""
    geometry = CityGeometry.of(method, spec)
    cells = tuple((origins // geometry.stride).T)
    n_views = geometry.membership.shape[1]
    if method == "flat_city_cnn":
        return output[(slice(None), *cells)].T * geometry.view_scale
    if method == "d_city_cnn":
        n = geometry.n_rays
        sub = boundary_subcells(state.ndim, n)
        index = (origins // geometry.stride)[:, None, :] * n + sub[None, :, :]
        rays = output[0][tuple(index.reshape(-1, state.ndim).T)].reshape(origins.shape[0], -1)
        return rays @ geometry.membership
    vectors = output[(slice(None), *cells)].T  # (N, 2|4)
    norms = np.linalg.norm(vectors, axis=1)
    unit = _view_vectors(spec)
    nearest = np.argmax(np.abs(vectors @ unit.T) if spec.dims == 3 else vectors @ unit.T, axis=1)
    gains = np.zeros((origins.shape[0], n_views), dtype=np.float32)
    gains[np.arange(origins.shape[0]), nearest] = norms * geometry.view_scale
    return gains


def predict(method: str, state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """The masked network output ``(C, *out_spatial)`` of a City-CNN on ``state``."""
    from nbv_prob_cnn.completion.inference import load_model, resolve_device

    device = resolve_device(None)
    model = load_model(None, context.defaults.name, device, model_name=method)
    if model.dims != state.ndim:
        raise ValueError(f"state: a {state.ndim}D grid does not fit a {model.dims}D {method} network")
    with torch.inference_mode():
        output = model(encode_city_input(state[None]).to(device))[0].float().cpu().numpy()
    return output * output_mask(CityGeometry.of(method, context.defaults), state)


class CityCnnPlanner(RankingPlanner):
    """One of the three City-CNN variants (by name)."""

    def __init__(self, method: str) -> None:
        self.name = method

    def rank_here(
        self, state: np.ndarray, context: PlanningContext, top_k: int, origin_filter: OriginFilter | None
    ) -> list[ViewChoice]:
        state = check_state(state)
        start = time.perf_counter()
        output = predict(self.name, state, context)
        t_cnn = time.perf_counter() - start
        origins = CityGeometry.of(self.name, context.defaults).origins(state)
        if origin_filter is not None:
            origins = origin_filter(origins)
        if origins.shape[0] == 0:
            return []
        views = decode_views(self.name, output, state, context.defaults, origins).ravel()
        k = min(max(1, top_k), views.size)
        best = np.argpartition(-views, k - 1)[:k] if k < views.size else np.arange(views.size)
        best = best[np.lexsort((best, -views[best]))]
        n_views = views.size // origins.shape[0]
        times = {"cnn": t_cnn, "raycast": 0.0, "views": time.perf_counter() - start - t_cnn}
        return [
            ViewChoice(origins[i // n_views].copy(), int(i % n_views), float(views[i]), dict(times))
            for i in best
            if views[i] > 0.0
        ]
