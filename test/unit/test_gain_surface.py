"""The surface blend of the ray gain (docs/method.md#surface-gain): hand-worked single rays, the
paper's gain unchanged at blend 0, OpenCL against the numpy reference, and the exact best view
against a brute-force search."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.gain import (
    GainSettings,
    best_origin_view,
    empty_origins,
    origin_view_gains,
    ray_directions,
    ray_gains,
    view_membership,
)
from nbv_prob_cnn.gain.sampling import GainSensor

BACKENDS = ["numpy", "opencl"]
from gain_grids import E, O, U, row_world  # noqa: E402


def _one_ray(state, prob, surface, backend, r_max=5):
    return ray_gains(state, prob, np.array([[1.0, 0.0]]), r_max, origins=np.array([[0, 1]]), backend=backend,
                     settings=GainSettings(surface=surface))[0, 0]  # fmt: skip


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_ray_surface_counts_where_the_return_lands(backend):
    # x:      0  1    2  3    4  5
    state, prob = row_world([E, U, E, U, O, U, E, E], [0, 0.5, 0, 0.2, 1, 0.9, 0, 0])
    # weights t = 0..5, sum 15. Pr at t1 = 1, at t3 = 0.5 (after p = 0.5); the occupied cell at t4
    # hides t5. Surface: sum of w_t Pr_t p_t over unknown samples = 1*1*0.5 + 3*0.5*0.2 = 0.8.
    assert _one_ray(state, prob, 1.0, backend) == pytest.approx(0.8 / 15, abs=1e-6)
    # paper's gain: 1*1 + 3*0.5 = 2.5; blend 0.25: 0.75 * 2.5 + 0.25 * 0.8 = 2.075
    assert _one_ray(state, prob, 0.0, backend) == pytest.approx(2.5 / 15, abs=1e-6)
    assert _one_ray(state, prob, 0.25, backend) == pytest.approx(2.075 / 15, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_known_surfaces_and_open_space_add_no_surface(backend):
    # unknown cells believed empty (p = 0) reveal space but no surface; the known occupied cell is
    # already seen and counts nothing
    state, prob = row_world([E, U, U, O, U, E], [0, 0.0, 0.0, 1, 1.0, 0])
    assert _one_ray(state, prob, 1.0, backend) == 0.0
    assert _one_ray(state, prob, 0.0, backend) == pytest.approx((1 + 2) / 15, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_certain_unknown_surface_counts_its_weight_once(backend):
    # an unknown cell that is surely occupied at t = 3: the return lands there (weight 9 of 30 in
    # 3D) and nothing behind it is reached
    state = np.full((3, 3, 6), O, dtype=np.int8)
    prob = np.ones(state.shape, dtype=np.float32)
    state[1, 1, :] = [E, E, E, U, U, U]
    prob[1, 1, :] = [0, 0, 0, 1.0, 0.5, 0.5]
    settings = GainSettings(surface=1.0)
    gains = ray_gains(state, prob, np.array([[0.0, 0.0, 1.0]]), 4, np.array([[1, 1, 0]]), backend, settings=settings)
    assert gains[0, 0] == pytest.approx(9 / 30, abs=1e-6)


def _random_world(rng, shape, unknown=0.5, occupied=0.12):
    draw = rng.random(shape)
    state = np.where(draw < unknown, U, np.where(draw < unknown + occupied, O, E)).astype(np.int8)
    prob = np.where(state == U, rng.random(shape), np.where(state == O, 1.0, 0.0)).astype(np.float32)
    return state, prob


@pytest.mark.parametrize("shape,n_rays,r_max", [((31, 27), 16, 18), ((15, 14, 12), 4, 9)])
@pytest.mark.parametrize("surface", [0.3, 1.0])
def test_opencl_matches_the_numpy_reference(shape, n_rays, r_max, surface):
    rng = np.random.default_rng(11)
    state, prob = _random_world(rng, shape)
    d = ray_directions(len(shape), n_rays)
    origins = empty_origins(state)[::3]
    settings = GainSettings(surface=surface)
    ref = ray_gains(state, prob, d, r_max, origins, "numpy", settings=settings)
    cl = ray_gains(state, prob, d, r_max, origins, "opencl", settings=settings)
    np.testing.assert_allclose(cl, ref, rtol=0, atol=1e-6)
    member = view_membership(d, orientations(len(shape)), 60.0, 46.0 if len(shape) == 3 else None)
    views = origin_view_gains(state, prob, d, r_max, member, origins, "opencl", settings=settings)
    np.testing.assert_allclose(views, ref.astype(np.float64) @ member, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("sampling,sensor", [("exact", None), ("rounded", GainSensor(1.0, 12.0, 75.0, True))])
def test_table_modes_match_the_reference(sampling, sensor):
    rng = np.random.default_rng(5)
    state, prob = _random_world(rng, (14, 13, 11))
    d = ray_directions(3, 4)
    origins = empty_origins(state)[::4]
    settings = GainSettings(surface=0.6, sampling=sampling, sensor=sensor)
    ref = ray_gains(state, prob, d, 9, origins, "numpy", settings=settings)
    cl = ray_gains(state, prob, d, 9, origins, "opencl", settings=settings)
    np.testing.assert_allclose(cl, ref, rtol=0, atol=1e-6)
    paper = ray_gains(state, prob, d, 9, origins, "numpy", settings=GainSettings(sampling=sampling, sensor=sensor))
    assert not np.allclose(ref, paper)  # the blend changes what is counted


@pytest.mark.parametrize("sensor", [None, GainSensor(1.0, 12.0, 75.0, True)])
def test_blend_zero_is_the_papers_gain_bit_for_bit(sensor):
    rng = np.random.default_rng(2)
    state, prob = _random_world(rng, (16, 15, 12))
    d = ray_directions(3, 4)
    origins = empty_origins(state)
    paper = ray_gains(state, prob, d, 9, origins, "opencl", settings=GainSettings(sensor=sensor))
    blend0 = ray_gains(state, prob, d, 9, origins, "opencl", settings=GainSettings(surface=0.0, sensor=sensor))
    assert np.array_equal(paper, blend0)


@pytest.mark.parametrize("shape,n_rays,r_max", [((30, 26), 16, 14), ((14, 13, 12), 4, 8)])
@pytest.mark.parametrize("surface", [0.5, 1.0])
def test_exact_best_view_equals_brute_force(shape, n_rays, r_max, surface):
    rng = np.random.default_rng(17)
    state, prob = _random_world(rng, shape, unknown=0.35)
    d = ray_directions(len(shape), n_rays)
    member = view_membership(d, orientations(len(shape)), 60.0, 46.0 if len(shape) == 3 else None)
    origins = empty_origins(state)
    settings = GainSettings(surface=surface)
    # brute force: every origin's every view from the numpy reference, argmax first in origin-major order
    brute = origin_view_gains(state, prob, d, r_max, member, origins, "numpy", settings=settings)
    flat = int(np.argmax(brute))
    index, view, gain = best_origin_view(state, prob, d, r_max, member, origins, "opencl", settings=settings)
    assert brute[index, view] == pytest.approx(brute.flat[flat], abs=2e-6)
    assert gain == pytest.approx(float(brute.flat[flat]), abs=2e-6)


@pytest.mark.parametrize(
    "fields,match",
    [
        ({"surface": 1.5}, "surface"),
        ({"surface": -0.1}, "surface"),
        ({"surface": float("nan")}, "surface"),
        ({"surface": 0.5, "mode": "ig"}, "surface"),
        ({"surface": 0.5, "variant": "original"}, "surface"),
    ],
)
def test_bad_blends_raise_value_error(fields, match):
    with pytest.raises(ValueError, match=match):
        GainSettings(**fields)


@pytest.mark.parametrize("surface", [0.5, 1.0])
def test_block_bounds_bound_every_origin_of_their_block(surface):
    """The coarse-to-fine search's block bounds of a blend (the ray's largest gain over every p
    in its windows' ranges) are at least every origin's exact view gains, and far tighter than
    the paper's bound at blend 1 (what makes the pruning pay: the window's largest p for the
    factor and its smallest for the visibility, taken apart, gave 0.8 of it and let 56 % of the
    origins of a half-explored 3DT grid through, against 2 % for cnn_prob)."""
    from nbv_prob_cnn.gain.march import ray_march
    from nbv_prob_cnn.gain.marched_grid import encode_grid
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    rng = np.random.default_rng(23)
    state, prob = _random_world(rng, (16, 15, 13), unknown=0.4)
    d = ray_directions(3, 4)
    member = view_membership(d, orientations(3), 60.0, 46.0)
    origins = empty_origins(state)
    settings = GainSettings(surface=surface)
    exact = origin_view_gains(state, prob, d, 9, member, origins, "numpy", settings=settings)
    caster = get_ray_caster()
    code = encode_grid(state, prob)
    block_of, bounds = caster.block_bounds(code, origins, ray_march(3, d, 9, settings), member)
    assert np.all(bounds[block_of] >= exact - 1e-6)
    _, paper_bounds = caster.block_bounds(code, origins, ray_march(3, d, 9, GainSettings()), member)
    if surface == 1.0:
        assert bounds.sum() < 0.4 * paper_bounds.sum()


@pytest.mark.parametrize("surface", [0.5, 1.0])
@pytest.mark.parametrize("dims", [2, 3])
def test_block_bounds_of_one_cell_blocks_are_the_exact_gains(surface, dims):
    """A block of one cell has windows of one cell (the smallest and largest p are its p): the
    bound (its dynamic programme, one choice per sample) must then give the exact gain of the numpy
    reference, view by view, in 2D and 3D."""
    from nbv_prob_cnn.gain.march import ray_march
    from nbv_prob_cnn.gain.marched_grid import encode_grid
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    rng = np.random.default_rng(29)
    state, prob = _random_world(rng, (15, 14, 12) if dims == 3 else (31, 27), unknown=0.45)
    d = ray_directions(dims, 4 if dims == 3 else 16)
    member = view_membership(d, orientations(dims), 60.0, 46.0 if dims == 3 else None)
    origins = empty_origins(state)
    settings = GainSettings(surface=surface)
    exact = origin_view_gains(state, prob, d, 9, member, origins, "numpy", settings=settings)
    block_of, bounds = get_ray_caster().block_bounds(
        encode_grid(state, prob), origins, ray_march(dims, d, 9, settings), member, size=1
    )
    np.testing.assert_allclose(bounds[block_of], exact, rtol=0, atol=1e-6)


@pytest.mark.parametrize("size", [1, 2, 3])
def test_block_bounds_keeping_the_samples_equal_gathering_them_again(monkeypatch, size):
    """The dynamic programme's backward pass reads the window ranges the march kept (``DP_SAMPLES``)
    or, for rays longer than :data:`~nbv_prob_cnn.gain.opencl.DP_KEPT_SAMPLES`, gathers them again:
    the same bounds, bit for bit (with one-cell blocks, the exact gains of the reference)."""
    from nbv_prob_cnn.gain import opencl
    from nbv_prob_cnn.gain.march import ray_march
    from nbv_prob_cnn.gain.marched_grid import encode_grid

    rng = np.random.default_rng(31)
    state, prob = _random_world(rng, (17, 14, 12), unknown=0.5)
    d = ray_directions(3, 4)
    member = view_membership(d, orientations(3), 60.0, 46.0)
    origins = empty_origins(state)
    settings = GainSettings(surface=0.9)
    code, march = encode_grid(state, prob), ray_march(3, d, 11, settings)
    caster = opencl.get_ray_caster()
    assert march.offsets.shape[1] <= opencl.DP_KEPT_SAMPLES  # kept by default
    block_of, kept = caster.block_bounds(code, origins, march, member, size=size)
    monkeypatch.setattr(opencl, "DP_KEPT_SAMPLES", 0)
    _, gathered = caster.block_bounds(code, origins, march, member, size=size)
    np.testing.assert_array_equal(kept, gathered)
    assert np.count_nonzero(kept) > kept.size // 4
    if size == 1:
        exact = origin_view_gains(state, prob, d, 11, member, origins, "numpy", settings=settings)
        np.testing.assert_allclose(kept[block_of], exact, rtol=0, atol=1e-6)
