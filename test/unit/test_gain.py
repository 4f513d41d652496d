"""Ray gain (docs/method.md#probabilistic-ray-casting-gain) on hand-worked grids, backend agreement, and validation."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.gain import GainSettings, origin_view_gains, ray_directions, ray_gains, view_gains, view_membership
from nbv_prob_cnn.gain.directions import distance_weights
from nbv_prob_cnn.gain.march import RayMarch
from nbv_prob_cnn.gain.reference import ray_terms

BACKENDS = ["numpy", "opencl"]
from gain_grids import E, O, U, row_world  # noqa: E402

IG = GainSettings(mode="ig")


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_ray_through_empty_unknown_occupied_2d(backend):
    # x:      0  1    2  3    4  5
    state, prob = row_world([E, U, E, U, O, U, E, E], [0, 0.5, 0, 0.2, 1, 0.9, 0, 0])
    gains = ray_gains(state, prob, np.array([[1.0, 0.0]]), 5, origins=np.array([[0, 1]]), backend=backend)
    # weights t = 0..5, sum 15; H = 1*1 (t1) + 0.5*3 (t3, after p=0.5) ; occupied at t4 hides t5
    assert gains.shape == (1, 1) and gains.dtype == np.float32
    assert gains[0, 0] == pytest.approx(2.5 / 15, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_grid_border_counts_as_occupied(backend):
    state, prob = row_world([E, E, E, E, U, U], [0, 0, 0, 0, 0.15, 0.15])
    gains = ray_gains(state, prob, np.array([[1.0, 0.0]]), 5, origins=np.array([[3, 1]]), backend=backend)
    # t1: x4 (Pr 1), t2: x5 (Pr 0.85), t3..5 outside the grid -> nothing
    assert gains[0, 0] == pytest.approx((1 * 1 + 0.85 * 2) / 15, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_diagonal_ray_with_occluder_samples_rounded_cells(backend):
    state = np.full((8, 8), U, dtype=np.int8)
    prob = np.full(state.shape, 0.5, dtype=np.float32)
    state[0, 0] = E
    prob[0, 0] = 0
    state[2, 2] = O  # occluder
    prob[2, 2] = 1
    direction = np.array([[1.0, 1.0]]) / np.sqrt(2)
    gains = ray_gains(state, prob, direction, 5, origins=np.array([[0, 0]]), backend=backend)
    # round(t/sqrt2) = 0, 1, 1, 2, 3, 4: cell (1,1) is sampled twice (t=1 Pr=1, t=2 Pr=0.5),
    # then (2,2) is occupied and hides the rest.
    assert gains[0, 0] == pytest.approx((1 * 1 + 0.5 * 2) / 15, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_ray_3d_uses_squared_distance(backend):
    state = np.full((3, 3, 6), O, dtype=np.int8)
    prob = np.ones(state.shape, dtype=np.float32)
    state[1, 1, :] = [E, U, U, U, O, U]
    prob[1, 1, :] = [0, 0.5, 0.5, 0.5, 1, 0.3]
    gains = ray_gains(state, prob, np.array([[0.0, 0.0, 1.0]]), 4, origins=np.array([[1, 1, 0]]), backend=backend)
    # weights t^2 = 0, 1, 4, 9, 16 (sum 30); H = 1 + 0.5*4 + 0.25*9
    assert gains[0, 0] == pytest.approx(5.25 / 30, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_information_gain_stops_at_first_non_empty(backend):
    state, _ = row_world([E, E, U, U, E, E], [0] * 6)
    gains = ray_gains(state, None, np.array([[1.0, 0.0]]), 5, np.array([[0, 1]]), backend, settings=IG)
    assert gains[0, 0] == pytest.approx(2 / 15, abs=1e-6)  # first non-empty: unknown at t=2
    beyond_3 = GainSettings(mode="ig", min_range=3)
    gains = ray_gains(state, None, np.array([[1.0, 0.0]]), 5, np.array([[0, 1]]), backend, settings=beyond_3)
    assert gains[0, 0] == 0.0  # the unknown cell is closer than the minimum range
    occluded, _ = row_world([E, O, U, U, U, U], [0] * 6)
    assert ray_gains(occluded, None, np.array([[1.0, 0.0]]), 5, np.array([[0, 1]]), backend, settings=IG)[0, 0] == 0


def test_ray_counts_and_unit_length():
    for dims, n, count in [(2, 16, 60), (3, 4, 56), (3, 16, 1352), (2, 4, 12)]:
        d = ray_directions(dims, n)
        assert d.shape == (count, dims)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
        np.testing.assert_allclose(d.sum(axis=0), 0.0, atol=1e-9)  # symmetric set
        assert len({tuple(np.round(v, 9)) for v in d}) == count  # all distinct
    # 3D, 4 per side: a face sub-cell centre (1.5, 0.5, 0.5) in sub-cell units from the cube centre
    assert any(
        np.allclose(v, np.array([1.5, 0.5, 0.5]) / np.linalg.norm([1.5, 0.5, 0.5])) for v in ray_directions(3, 4)
    )


def _random_world(rng, shape):
    state = rng.choice(np.array([U, E, O], dtype=np.int8), size=shape, p=[0.45, 0.45, 0.1])
    prob = rng.random(shape).astype(np.float32)
    prob[state == E] = 0
    prob[state == O] = 1
    return state, prob


@pytest.mark.parametrize("shape,n_rays,r_max", [((37, 29), 16, 24), ((17, 15, 13), 4, 9), ((12, 11, 10), 16, 7)])
def test_backends_agree_on_random_grids(rng, shape, n_rays, r_max):
    state, prob = _random_world(rng, shape)
    d = ray_directions(len(shape), n_rays)
    a = ray_gains(state, prob, d, r_max, backend="numpy")
    b = ray_gains(state, prob, d, r_max, backend="opencl")
    assert a.shape == (np.count_nonzero(state == E), d.shape[0])
    assert a.max() > 0.05  # a meaningful comparison, not all zeros
    np.testing.assert_allclose(a, b, atol=1e-5)
    ig_a = ray_gains(state, None, d, r_max, backend="numpy", settings=IG)
    ig_b = ray_gains(state, None, d, r_max, backend="opencl", settings=IG)
    np.testing.assert_allclose(ig_a, ig_b, atol=1e-6)


def test_hit_plus_miss_is_constant(rng):
    for shape, dims_rays in [((30, 30), 16), ((12, 12, 12), 4)]:
        state, prob = _random_world(rng, shape)
        d = ray_directions(len(shape), dims_rays)
        hit, miss = ray_terms(state, prob, d, 10, np.argwhere(state == E))
        np.testing.assert_allclose(hit + miss, distance_weights(10, len(shape)).sum(), rtol=1e-12)


def test_tolerance_bound_holds(rng):
    state, prob = _random_world(rng, (20, 20, 20))
    prob[state == U] = 0.02  # long rays, Pr decays slowly
    d = ray_directions(3, 4)
    exact = ray_gains(state, prob, d, 12, backend="opencl")
    approx = ray_gains(state, prob, d, 12, backend="opencl", settings=GainSettings(eps=0.3))
    assert np.all(approx <= exact + 1e-6)
    assert np.all(exact - approx <= 0.3 + 1e-6)


def test_view_gains_sum_rays_in_frustum():
    d = ray_directions(2, 16)
    g = np.zeros((1, d.shape[0]), dtype=np.float32)
    angles = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    g[0, np.argmin(np.abs(angles - 3.0))] = 1.0  # the ray nearest to +3 deg
    yaws = np.deg2rad(np.arange(0, 360, 6))
    w = view_gains(g, d, yaws, 60.0)
    assert w.shape == (1, 60)
    ray_angle = angles[np.argmin(np.abs(angles - 3.0))]
    expected = [abs((ray_angle - y + 180) % 360 - 180) <= 30 for y in np.arange(0, 360, 6)]
    np.testing.assert_array_equal(w[0] > 0, expected)
    assert 9 <= sum(expected) <= 11


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"state": np.zeros((4, 4), dtype=np.float32)}, "state"),
        ({"state": np.full((4, 4), 2, dtype=np.int8)}, "state"),
        ({"state": np.zeros(16, dtype=np.int8)}, "state"),
        ({"prob": np.zeros((4, 5), dtype=np.float32)}, "prob"),
        ({"prob": np.full((4, 4), np.nan, dtype=np.float32)}, "prob"),
        ({"prob": np.full((4, 4), 1.5, dtype=np.float32)}, "prob"),
        ({"directions": np.ones((3, 3))}, "directions"),
        ({"r_max": 0}, "r_max"),
        ({"origins": np.array([[9, 9]])}, "origins"),
        ({"origins": np.array([[0.5, 1.0]])}, "origins"),
        ({"backend": "cuda"}, "backend"),
    ],
)
def test_bad_inputs_raise_value_error(kwargs, match):
    args = {
        "state": np.zeros((4, 4), dtype=np.int8),
        "prob": np.zeros((4, 4), dtype=np.float32),
        "directions": ray_directions(2, 4),
        "r_max": 3,
        "origins": None,
        "backend": "numpy",
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ray_gains(**args)


@pytest.mark.parametrize(
    "fields,match",
    [
        ({"mode": "gain"}, "mode"),
        ({"eps": 1.0}, "eps"),
        ({"eps": float("nan")}, "eps"),
        ({"min_range": np.inf}, "min_range"),
    ],
)
def test_bad_settings_raise_value_error(fields, match):
    with pytest.raises(ValueError, match=match):
        GainSettings(**fields)


def test_settings_must_be_gain_settings():
    state = np.zeros((4, 4), dtype=np.int8)
    with pytest.raises(ValueError, match="settings"):
        ray_gains(state, np.zeros((4, 4), np.float32), ray_directions(2, 4), 3, settings={"mode": "ig"})  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "shape,n_rays,r_max",
    [((41, 37), 4, 20), ((41, 37), 16, 20), ((17, 15, 13), 4, 9), ((13, 12, 11), 16, 7)],
)
@pytest.mark.parametrize("mode", ["prob", "ig"])
def test_fused_view_gains_match_numpy_reference(rng, shape, n_rays, r_max, mode):
    """The fused OpenCL view-gain kernel against the numpy reference (per-ray gains summed over
    each view's rays): same best view, every view gain within 1e-4."""
    state, prob = _random_world(rng, shape)
    dims = len(shape)
    d = ray_directions(dims, n_rays)
    yaws_or_quats = orientations(dims)
    member = view_membership(d, yaws_or_quats, 60.0, None if dims == 2 else 46.0)
    origins = np.argwhere(state == E)
    p = prob if mode == "prob" else None
    settings = GainSettings(mode=mode, min_range=2)
    expected = view_gains(ray_gains(state, p, d, r_max, origins, "numpy", settings=settings), d, yaws_or_quats,
                          60.0, None if dims == 2 else 46.0)  # fmt: skip
    got = origin_view_gains(state, p, d, r_max, member, origins, "opencl", settings=settings)
    assert got.shape == expected.shape == (origins.shape[0], yaws_or_quats.shape[0])
    assert expected.max() > 0.05  # a meaningful comparison, not all zeros
    np.testing.assert_allclose(got, expected, atol=1e-4, rtol=0)
    assert np.argmax(got) == np.argmax(expected)
    # the numpy backend of the same function is the reference itself (float32 products of
    # different shapes: BLAS may sum in another order, a few ulp)
    np.testing.assert_allclose(origin_view_gains(state, p, d, r_max, member, origins[:50], "numpy",
                                                 settings=settings), expected[:50], atol=1e-6, rtol=1e-6)  # fmt: skip


def test_fused_view_gains_hand_worked_2d():
    # one ray to +x through (E, U 0.5, E, U 0.2, O): G_r = (1 + 0.5 * 3) / 15 with r_max 5
    state, prob = row_world([E, U, E, U, O, U, E, E], [0, 0.5, 0, 0.2, 1, 0.9, 0, 0])
    d = np.array([[1.0, 0.0], [-1.0, 0.0]])
    member = np.array([[1, 0, 1], [0, 1, 1]], dtype=np.float32)  # views: +x only, -x only, both
    got = origin_view_gains(state, prob, d, 5, member, np.array([[0, 1]]), "opencl")
    np.testing.assert_allclose(got, [[2.5 / 15, 0.0, 2.5 / 15]], atol=1e-7)


def test_fused_view_gains_bad_membership():
    state = np.zeros((4, 4), dtype=np.int8)
    with pytest.raises(ValueError, match="membership"):
        origin_view_gains(state, np.zeros((4, 4), np.float32), ray_directions(2, 4), 3, np.ones((5, 2)), None, "numpy")


@pytest.fixture(scope="module")
def lane_casters():
    """One OpenCL ray caster per lane width (origins marched per work-item), built once."""
    from nbv_prob_cnn.gain.opencl import LANE_WIDTHS, OpenCLRayCaster

    return {lanes: OpenCLRayCaster(lanes) for lanes in LANE_WIDTHS}


@pytest.mark.parametrize("shape,n_rays,r_max", [((41, 37), 16, 20), ((13, 12, 11), 16, 7), ((17, 15, 13), 4, 9)])
@pytest.mark.parametrize("mode", ["prob", "ig"])
def test_every_lane_width_matches_numpy_reference(rng, lane_casters, shape, n_rays, r_max, mode):
    """The kernels marching 1, 2, 4, 8 or 16 origins per work-item (1 on a GPU, 16 on a CPU by
    default): ray and view gains within 1e-4 of the numpy reference with its best view, and the
    same float32 values for every width (each lane does the scalar loop's operations). Origin
    counts that fill no whole vector or work-group (padding) and a tolerance ``eps`` included."""
    from nbv_prob_cnn.gain.directions import sample_offsets
    from nbv_prob_cnn.gain.marched_grid import encode_grid

    state, prob = _random_world(rng, shape)
    dims = len(shape)
    d = ray_directions(dims, n_rays)
    member = view_membership(d, orientations(dims), 60.0, None if dims == 2 else 46.0)
    origins = np.argwhere(state == E)[:203]
    p = prob if mode == "prob" else None
    settings = GainSettings(mode=mode, min_range=2)
    expected_rays = ray_gains(state, p, d, r_max, origins, "numpy", settings=settings)
    expected = expected_rays @ member
    code, offsets = encode_grid(state, p), sample_offsets(d, r_max)
    total = float(distance_weights(r_max, dims).sum())
    first: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # per eps: the first width's gains
    for lanes, caster in lane_casters.items():
        for eps in (0.0, 0.05):
            march = RayMarch(offsets, total, mode, eps, 2.0)
            got_rays, got = caster.run(code, origins, march), caster.run_views(code, origins, march, member)
            if eps == 0.0:
                np.testing.assert_allclose(got_rays, expected_rays, atol=1e-5, rtol=0, err_msg=f"lanes {lanes}")
                np.testing.assert_allclose(got, expected, atol=1e-4, rtol=0, err_msg=f"lanes {lanes}")
                assert np.argmax(got) == np.argmax(expected)
            first.setdefault(eps, (got_rays, got))
            np.testing.assert_array_equal(got_rays, first[eps][0], err_msg=f"lanes {lanes} eps {eps}")
            np.testing.assert_array_equal(got, first[eps][1], err_msg=f"lanes {lanes} eps {eps}")
    assert expected.max() > 0.05


def test_bad_lane_width():
    from nbv_prob_cnn.gain.opencl import OpenCLRayCaster

    with pytest.raises(ValueError, match="lanes"):
        OpenCLRayCaster(3)


def test_sample_offsets_by_hand():
    """``round(t b)`` with halves rounded up: (0.6, 0.8) gives (0,0) (1,1) (1,2) (2,2); (0.5, 0.866)
    at t = 1 gives (1, 1) (0.5 rounds up)."""
    from nbv_prob_cnn.gain.directions import sample_offsets

    got = sample_offsets(np.array([[0.6, 0.8], [0.5, np.sqrt(0.75)]]), 3)
    assert got.dtype == np.int16 and got.shape == (2, 4, 2)
    np.testing.assert_array_equal(got[0], [[0, 0], [1, 1], [1, 2], [2, 2]])
    np.testing.assert_array_equal(got[1, 1], [1, 1])


def test_grouped_sample_offsets_equal_one_table_and_are_kept(rng, monkeypatch):
    """Set by set, with each set's table kept (read-only, the same values on the next call), the
    offsets equal :func:`sample_offsets` of all the rays; the kept tables stay within the byte budget
    (the least recently used dropped)."""
    from nbv_prob_cnn.gain import directions as module

    rays = rng.normal(size=(4 * 30, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    expected = module.sample_offsets(rays, 17)
    tables = module._OffsetTables()
    monkeypatch.setattr(module, "_OFFSET_TABLES", tables)
    for _ in range(2):
        np.testing.assert_array_equal(module.grouped_sample_offsets(rays, 17, 4), expected)
    assert len(tables._tables) == 4 and not next(iter(tables._tables.values())).flags.writeable
    one = expected[:30].nbytes
    monkeypatch.setattr(module, "OFFSET_CACHE_BYTES", 2 * one)
    np.testing.assert_array_equal(module.grouped_sample_offsets(rays[:60], 9, 2), module.sample_offsets(rays[:60], 9))
    assert tables._bytes <= 2 * one and len(tables._tables) == 2  # the two newest: range 9
    assert all(key[2] == 9 for key in tables._tables)
    with pytest.raises(ValueError, match="groups"):
        module.grouped_sample_offsets(rays, 17, 7)


@pytest.mark.parametrize("edit", ["in place", "new array"])
def test_ray_caster_marches_a_changed_grid_again(rng, edit):
    """The caster keeps the last marched grid for a launch on an equal grid: a grid changed since
    (the same array edited in place, or another array) is marched anew; gains equal the reference's."""
    from nbv_prob_cnn.gain import each_origin_ray_gains

    state = rng.choice(np.array([E, U, O], dtype=np.int8), size=(12, 11, 10), p=[0.5, 0.4, 0.1])
    prob = rng.uniform(0.05, 0.95, size=state.shape).astype(np.float32)
    origins = np.argwhere(state == E)[:9]
    d = ray_directions(3, 3)
    own = np.stack([d[rng.permutation(d.shape[0])[:6]] for _ in range(origins.shape[0])])
    for step in range(3):
        expected = each_origin_ray_gains(state, prob, own, 9, origins, "numpy")
        for launch in range(2):  # OpenCL on the same grid twice: the second on the kept grid
            got = each_origin_ray_gains(state, prob, own, 9, origins, "opencl")
            np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0, err_msg=f"step {step} launch {launch}")
        unknown = np.argwhere(state == U)
        flip = unknown[rng.permutation(unknown.shape[0])[:20]]
        if edit == "new array":
            state = state.copy()
        state[tuple(flip.T)] = O  # new surface hides what was behind it


def test_ray_caster_keeps_a_copy_of_the_last_grid(rng):
    """The grid code edited in place after a launch is not taken for the grid launched before."""
    from nbv_prob_cnn.gain.directions import sample_offsets
    from nbv_prob_cnn.gain.marched_grid import encode_grid
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    state = rng.choice(np.array([E, U], dtype=np.int8), size=(10, 9, 8), p=[0.5, 0.5])
    code = encode_grid(state, np.full(state.shape, 0.5, np.float32))
    d = ray_directions(3, 3)
    march = RayMarch(sample_offsets(d, 8), float(distance_weights(8, 3).sum()))
    origins = np.argwhere(state == E)[:5]
    caster = get_ray_caster()
    before = caster.run(code, origins, march)
    code[code >= 0.0] = 0.9  # every unknown cell now likelier occupied: other gains
    after = caster.run(code, origins, march)
    np.testing.assert_array_equal(after, caster.run(code.copy(), origins, march))
    assert not np.allclose(before, after)
