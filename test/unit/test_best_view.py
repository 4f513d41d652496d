"""Coarse-to-fine best-view search (``best_origin_view``): exact for the argmax."""

import functools

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.gain import (
    GainSettings,
    _grid_code,
    best_origin_view,
    origin_view_gains,
    ray_directions,
    view_membership,
)
from nbv_prob_cnn.gain.directions import distance_weights, sample_offsets
from nbv_prob_cnn.gain.march import RayMarch, march_options, ray_march
from nbv_prob_cnn.gain.marched_grid import encode_grid
from nbv_prob_cnn.gain.opencl import get_ray_caster

E, O, U = 0, 1, -1  # noqa: E741


def _explored_world(
    rng: np.random.Generator, shape: tuple[int, ...], explored_fraction: float = 0.6
) -> tuple[np.ndarray, np.ndarray]:
    """Unknown space with an explored (empty) box on one side (``explored_fraction`` of each
    axis), occupied boxes in and around it, and smooth-ish random probabilities: gains differ a
    lot between origins (pruning happens)."""
    state = np.full(shape, U, dtype=np.int8)
    explored = tuple(slice(1, max(2, int(explored_fraction * s))) for s in shape)
    state[explored] = E
    for _ in range(4):
        lo = [int(rng.integers(0, s - 3)) for s in shape]
        state[tuple(slice(a, a + int(rng.integers(2, 5))) for a in lo)] = O
    noise = rng.random(shape).astype(np.float32)
    prob = np.where(state == U, 0.05 + 0.9 * noise**3, (state == O).astype(np.float32)).astype(np.float32)
    return state, prob


def _setup(shape, n_rays):
    dims = len(shape)
    d = ray_directions(dims, n_rays)
    member = view_membership(d, orientations(dims), 60.0, None if dims == 2 else 46.0)
    return d, member


def _explored_views(seed: int, shape, n_rays: int, mode: str):
    """:func:`_explored_world` of ``seed``: its state, the probabilities (``prob`` mode; None for
    ``ig``), the ray directions and view membership, and the origins (every empty cell)."""
    state, prob = _explored_world(np.random.default_rng(seed), shape)
    d, member = _setup(shape, n_rays)
    return state, (prob if mode == "prob" else None), d, member, np.argwhere(state == E)


def _march(d, r_max, mode="prob", min_range=2.0):
    """The paper's rounded samples of ``d`` up to ``r_max`` (exact: ``eps`` 0)."""
    return RayMarch(sample_offsets(d, r_max), float(distance_weights(r_max, d.shape[1]).sum()), mode, 0.0, min_range)


CASES = [((40, 36), 16, 24), ((41, 37), 4, 30), ((19, 17, 15), 4, 12), ((16, 15, 17), 4, 9), ((14, 13, 12), 16, 8)]


@pytest.mark.parametrize("shape,n_rays,r_max", CASES)
@pytest.mark.parametrize("mode", ["prob", "ig"])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("block_size", [2, 4])
def test_best_view_equals_exhaustive_and_numpy(shape, n_rays, r_max, mode, seed, block_size):
    """Same (origin, view) as the exhaustive OpenCL argmax, gain within 1e-4 of the numpy
    reference, and a maximum of the reference: the reference's argmax itself unless another pair
    is within 1e-6 (relative, plus 1e-6) of it (``ig`` sums equal weights: exact ties that float32 and float64 sums in
    different orders break differently)."""
    state, p, d, member, origins = _explored_views(seed, shape, n_rays, mode)
    settings = GainSettings(mode=mode, min_range=2)
    exhaustive = origin_view_gains(state, p, d, r_max, member, origins, "opencl", settings=settings)
    reference = origin_view_gains(state, p, d, r_max, member, origins, "numpy", settings=settings)
    code = encode_grid(state, p)
    index, view, gain, _ = get_ray_caster().best_view(
        code, origins, _march(d, r_max, mode), member, first_batch=16, block_size=block_size
    )
    assert (index, view, gain) == best_origin_view(state, p, d, r_max, member, origins, "opencl",
                                                   settings=settings) or block_size != 2  # fmt: skip
    assert reference.max() > 0.05
    flat = int(np.argmax(exhaustive))
    assert (index, view) == divmod(flat, exhaustive.shape[1])
    assert reference[index, view] >= reference.max() * (1 - 1e-6) - 1e-6
    assert gain == exhaustive.flat[flat]
    assert abs(gain - reference.max()) <= 1e-4


@functools.cache
def _late_exploration(shape, n_rays, r_max):
    """The late-exploration grid, rays, views, origins and the numpy reference's gains: computed
    once for both lane widths (the reference does not depend on them)."""
    state, prob = _explored_world(np.random.default_rng(7), shape, explored_fraction=1.0)
    d, member = _setup(shape, n_rays)
    origins = np.argwhere(state == E)
    reference = origin_view_gains(state, prob, d, r_max, member, origins, "numpy", settings=GainSettings(min_range=2))
    return state, prob, d, member, origins, reference


@pytest.mark.parametrize("shape,n_rays,r_max", [((18, 17, 16), 16, 10), ((44, 40), 16, 24)])
@pytest.mark.parametrize("lanes", [1, None])
def test_best_view_late_exploration(shape, n_rays, r_max, lanes):
    """Late in an exploration (all but one layer of each axis explored: many origins, little unknown
    left, N_rays=16) with the CPU's default lane width and with one origin per work-item (a GPU's):
    the exhaustive argmax, gain within 1e-4 of the numpy reference's maximum."""
    from nbv_prob_cnn.gain.opencl import OpenCLRayCaster

    state, prob, d, member, origins, reference = _late_exploration(shape, n_rays, r_max)
    caster = get_ray_caster() if lanes is None else OpenCLRayCaster(lanes)
    code, march = encode_grid(state, prob), _march(d, r_max)
    exhaustive = caster.run_views(code, origins, march, member)
    index, view, gain, evaluated = caster.best_view(code, origins, march, member, first_batch=16)
    assert np.count_nonzero(state == U) < 0.25 * state.size and reference.max() > 0.01
    assert (index, view) == divmod(int(np.argmax(exhaustive)), exhaustive.shape[1])
    assert gain == exhaustive.max() and abs(gain - reference.max()) <= 1e-4
    assert reference[index, view] >= reference.max() * (1 - 1e-6) - 1e-6
    assert evaluated < origins.shape[0]


@pytest.mark.parametrize("shape,n_rays,r_max", CASES)
@pytest.mark.parametrize("mode", ["prob", "ig"])
@pytest.mark.parametrize("size", [2, 3, 4])
def test_block_bounds_bound_every_origin(shape, n_rays, r_max, mode, size):
    """Each block's per-view bound is at least the exact gain of every origin of the block."""
    state, p, d, member, origins = _explored_views(2, shape, n_rays, mode)
    exact = origin_view_gains(
        state, p, d, r_max, member, origins, "numpy", settings=GainSettings(mode=mode, min_range=2)
    )
    code = encode_grid(state, p)
    block_of, bounds = get_ray_caster().block_bounds(code, origins, _march(d, r_max, mode), member, size)
    assert block_of.shape == (origins.shape[0],) and bounds.shape[1] == member.shape[1]
    assert bounds.shape[0] < origins.shape[0]  # blocks gather several origins
    assert np.all(bounds[block_of] >= exact - 1e-5)
    assert (bounds[block_of] - exact).min() < 0.5 * exact.max()  # tight somewhere, not a trivial bound
    # every block is a corner's window: origins of one block lie within size - 1 cells per axis
    for block in np.unique(block_of)[:50]:
        members = origins[block_of == block]
        assert np.all(members.max(axis=0) - members.min(axis=0) <= size - 1)


def test_best_view_prunes_origins():
    """Unknown space only in one corner: origins out of its reach are never evaluated exactly,
    the result is unchanged."""
    shape, n_rays, r_max = (48, 44, 40), 4, 16
    state = np.zeros(shape, dtype=np.int8)
    state[:12, :12, :12] = U
    state[14:18, 5:9, 3:20] = O
    prob = np.where(state == U, 0.3, (state == O).astype(np.float32)).astype(np.float32)
    d, member = _setup(shape, n_rays)
    origins = np.argwhere(state == E)
    code = encode_grid(state, prob)
    index, view, gain, evaluated = get_ray_caster().best_view(
        code, origins, _march(d, r_max, min_range=0.0), member, first_batch=64
    )
    exhaustive = origin_view_gains(state, prob, d, r_max, member, origins, "opencl")
    assert (index, view) == divmod(int(np.argmax(exhaustive)), exhaustive.shape[1])
    assert gain == exhaustive.max() > 0
    assert evaluated < origins.shape[0] // 4


def test_best_view_ties_go_to_first_origin():
    """All origins equal (symmetric empty corridor ends): the first origin and view, as argmax."""
    state = np.full((9, 9), O, dtype=np.int8)
    state[2:7, 4] = E
    state[1, 4] = state[7, 4] = U
    prob = np.where(state == U, 0.5, (state == O).astype(np.float32)).astype(np.float32)
    d, member = _setup(state.shape, 16)
    origins = np.argwhere(state == E)
    exhaustive = origin_view_gains(state, prob, d, 8, member, origins, "opencl")
    index, view, gain = best_origin_view(state, prob, d, 8, member, origins, "opencl")
    assert (index, view) == divmod(int(np.argmax(exhaustive)), exhaustive.shape[1])
    assert gain == exhaustive.max() > 0


def test_best_view_no_origins_and_bad_membership():
    state = np.zeros((6, 6), dtype=np.int8)
    d, member = _setup(state.shape, 4)
    prob = np.zeros(state.shape, dtype=np.float32)
    assert best_origin_view(state, prob, d, 5, member, np.zeros((0, 2), dtype=np.int64), "opencl")[0] == -1
    with pytest.raises(ValueError, match="membership"):
        best_origin_view(state, prob, d, 5, member[:-1], None, "opencl")


def test_best_view_sparse_origins_evaluated_exhaustively():
    """Scattered origins (one per block): no bounds, every origin evaluated, same argmax."""
    shape, r_max = (19, 17, 15), 10
    state, prob = _explored_world(np.random.default_rng(4), shape)
    d, member = _setup(shape, 4)
    origins = np.argwhere(state == E)[::9]
    code = encode_grid(state, prob)
    index, view, gain, evaluated = get_ray_caster().best_view(code, origins, _march(d, r_max, min_range=0.0), member)
    reference = origin_view_gains(state, prob, d, r_max, member, origins, "numpy")
    assert evaluated == origins.shape[0]
    assert (index, view) == divmod(int(np.argmax(reference)), reference.shape[1])
    assert abs(gain - reference.max()) <= 1e-4


@pytest.mark.parametrize("shape,n_rays,r_max", [((19, 17, 15), 16, 8), ((40, 36), 16, 24)])
@pytest.mark.parametrize("mode", ["prob", "ig"])
def test_view_sets_give_exact_gains_of_their_views(shape, n_rays, r_max, mode):
    """View sets: one set for every origin gives the reference gains of its views and 0 for the
    others (their rays are not marched); per-origin sets sum a work-group's union of views, so
    every origin's own views are exact and every other view is exact or 0."""
    state, p, d, member, origins = _explored_views(5, shape, n_rays, mode)
    reference = origin_view_gains(
        state, p, d, r_max, member, origins, "numpy", settings=GainSettings(mode=mode, min_range=2)
    )
    code, march = encode_grid(state, p), _march(d, r_max, mode)
    rng = np.random.default_rng(6)
    keep = rng.random(member.shape[1]) < 0.3
    shared = np.repeat(keep[None], origins.shape[0], axis=0)
    got = get_ray_caster().run_views(code, origins, march, member, view_sets=shared)
    assert np.abs(got - reference * keep).max() <= 1e-4
    assert (reference * keep).max() > 0.05 and (reference * ~keep).max() > 0.05  # both parts meaningful
    own = rng.random((origins.shape[0], member.shape[1])) < 0.2
    mixed = get_ray_caster().run_views(code, origins, march, member, view_sets=own)
    exact = np.abs(mixed - reference) <= 1e-4
    assert np.all(exact[own]) and np.all(exact | (mixed == 0.0))
    assert np.count_nonzero(~exact & (reference > 0)) > 0  # some views really left out


@pytest.mark.parametrize("mode", ["prob", "ig"])
def test_best_view_evaluates_only_views_that_can_win(monkeypatch, mode):
    """After the first batch, origins evaluate (and march the rays of) only the views whose
    block bound reaches the best gain: the same (origin, view, gain) as the exhaustive search
    and the numpy reference."""
    import nbv_prob_cnn.gain.opencl as opencl

    shape, n_rays, r_max = (20, 18, 16), 16, 10
    state, p, d, member, origins = _explored_views(7, shape, n_rays, mode)
    evaluated: list[float] = []

    def spy(*args):
        row, sets = reaching_views(*args)
        evaluated.append(float(sets[row].mean()))
        return row, sets

    reaching_views = opencl.reaching_views
    monkeypatch.setattr(opencl, "reaching_views", spy)
    code = encode_grid(state, p)
    index, view, gain, _ = get_ray_caster().best_view(code, origins, _march(d, r_max, mode), member, first_batch=8)
    settings = GainSettings(mode=mode, min_range=2)
    reference = origin_view_gains(state, p, d, r_max, member, origins, "numpy", settings=settings)
    exhaustive = origin_view_gains(state, p, d, r_max, member, origins, "opencl", settings=settings)
    assert evaluated and max(evaluated) < 1.0 and min(evaluated) < 0.75  # view sets really shrink
    assert (index, view) == divmod(int(np.argmax(exhaustive)), exhaustive.shape[1])
    assert gain == exhaustive.max()
    assert reference[index, view] >= reference.max() * (1 - 1e-6) - 1e-6  # a reference maximum
    assert abs(gain - reference.max()) <= 1e-4


@pytest.mark.parametrize("width", [5, 33, 52, 64, 65, 130])
def test_unique_rows_matches_numpy_unique(width):
    """The 64-bit-key fast path (width <= 64) and the word path give numpy's distinct rows and
    an inverse that rebuilds the input."""
    from nbv_prob_cnn.gain.view_tables import unique_rows

    rng = np.random.default_rng(width)
    flags = rng.random((400, width)) < 0.5
    flags[200:] = flags[:200]  # repeated rows
    flags[0, -1], flags[1, -1] = True, False  # the last bit matters
    rows, inverse = unique_rows(flags)
    assert np.array_equal(rows[inverse], flags)
    assert rows.shape[0] == np.unique(flags, axis=0).shape[0]


def _exhaustive_top(gains: np.ndarray, top_k: int) -> list[tuple[int, int, float]]:
    """The ``top_k`` positive entries of ``gains`` by a plain sort: gain descending, then origin, then view."""
    entries = [(-float(g), i, v) for (i, v), g in np.ndenumerate(gains) if g > 0.0]
    return [(i, v, -g) for g, i, v in sorted(entries)[:top_k]]


@pytest.mark.parametrize("shape,n_rays,r_max", CASES)
@pytest.mark.parametrize("surface", [0.0, 0.9])
@pytest.mark.parametrize("masked", [False, True])
def test_best_views_rank_as_a_sort_of_every_gain(shape, n_rays, r_max, surface, masked):
    """The bounded top-k search returns the first ``top_k`` of a plain sort of the exhaustive OpenCL
    gains (with a random view mask: of the allowed ones), for a k that forces it past the first batch."""
    from nbv_prob_cnn.gain import best_origin_views

    state, p, d, member, origins = _explored_views(3, shape, n_rays, "prob")
    settings = GainSettings(mode="prob", min_range=2, surface=surface)
    gains = origin_view_gains(state, p, d, r_max, member, origins, "opencl", settings=settings)
    allowed = np.random.default_rng(5).random(gains.shape) > 0.3 if masked else None
    if allowed is not None:
        gains = np.where(allowed, gains, 0.0)
    march = ray_march(len(shape), d, r_max, settings, march_options(state, p, d, r_max, settings))
    evaluated = []
    for top_k in (1, 5, 40):
        expected = _exhaustive_top(gains, top_k)
        assert len(expected) == top_k
        found = best_origin_views(state, p, d, r_max, member, origins, top_k, allowed, settings=settings, block_size=2)
        # small batches: the search stops at the bound of the k-th best
        *small, done = get_ray_caster().best_views(_grid_code(state, p, settings), origins, march, member, top_k,
                                                   allowed, first_batch=8, block_size=2)  # fmt: skip
        evaluated.append(done)
        for index, view, gain in (found, small):
            assert list(zip(index.tolist(), view.tolist(), strict=True)) == [(i, v) for i, v, _ in expected]
            np.testing.assert_array_equal(gain, np.float32([g for _, _, g in expected]))
    assert evaluated[0] <= evaluated[1] <= evaluated[2] <= origins.shape[0]  # a lower bar lets more origins through
    if surface == 0.0 and len(shape) == 3:
        assert evaluated[0] < origins.shape[0]  # pruning happened


def test_best_views_rejects_bad_arguments():
    from nbv_prob_cnn.gain import best_origin_views

    state, p, d, member, origins = _explored_views(0, (19, 17, 15), 4, "prob")
    with pytest.raises(ValueError, match="top_k"):
        best_origin_views(state, p, d, 8, member, origins, 0)
    with pytest.raises(ValueError, match="allowed"):
        best_origin_views(state, p, d, 8, member, origins, 3, np.ones((2, 2), dtype=bool))
