"""The optional gain modes (docs/sensing.md): the "returns" sensor model and the
exact-traversal sampling, on the one gain kernel, against hand-worked rays, the numpy reference,
a slow ray-box traversal, and the exhaustive argmax for the pruned search."""

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.gain import (
    GainSensor,
    GainSettings,
    best_origin_view,
    origin_view_gains,
    ray_directions,
    ray_gains,
    view_membership,
)
from nbv_prob_cnn.gain.opencl import LANE_WIDTHS, SENSOR_MAX_LANES, OpenCLRayCaster
from nbv_prob_cnn.gain.sampling import ray_samples, traversal_table
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.planners.base import search_best_view
from nbv_prob_cnn.sensing.sensor_noise import sensor_noise

BACKENDS = ("opencl", "numpy")
PLUS_X = np.array([[1.0, 0.0]])
R_MAX = 20
PAPER_TOTAL = sum(range(R_MAX + 1))  # sum of t for t = 0 .. 20 (2D: nu = 1)


def _row(length: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """A 2D grid of one open row y = 1 (rows 0 and 2 occupied): origin (1, 1) empty, the rest of
    the row unknown with probability 0 (set per test)."""
    state = np.ones((length, 3), dtype=np.int8)
    state[:, 1] = -1
    state[1, 1] = 0
    return state, np.zeros(state.shape, dtype=np.float32)


def _gain(state, prob, backend, sensor=None, sampling="rounded") -> float:
    origin = np.array([[1, 1]])
    settings = GainSettings(sensor=sensor, sampling=sampling)
    return float(ray_gains(state, prob, PLUS_X, R_MAX, origin, backend, settings=settings)[0, 0])


@pytest.mark.parametrize("backend", BACKENDS)
def test_wall_at_known_distance_by_hand(backend):
    # samples t = 1..8 unknown (p = 0), t = 9 a known occupied cell: the return at 9 is certain
    state, prob = _row()
    state[10, 1] = 1
    expected = sum(range(1, 9)) / PAPER_TOTAL  # 36 / 210
    assert _gain(state, prob, backend) == pytest.approx(expected, rel=1e-6)
    assert _gain(state, prob, backend, GainSensor(0.0, 50.0)) == pytest.approx(expected, rel=1e-6)
    # a minimum range beyond the wall: its return is no measurement, nothing counts
    assert _gain(state, prob, backend, GainSensor(12.0, 50.0)) == 0.0
    # a maximum range short of the wall: no return either
    assert _gain(state, prob, backend, GainSensor(0.0, 6.0)) == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_minimum_and_maximum_range_cut_the_returns_by_hand(backend):
    # t = 2 unknown with p = 0.5, the wall at t = 9: first return at 2 or 9, each with probability 0.5
    state, prob = _row()
    state[10, 1] = 1
    prob[3, 1] = 0.5
    paper = (1 + 2 + 0.5 * sum(range(3, 9))) / PAPER_TOTAL  # every ray returns: the paper's gain
    assert _gain(state, prob, backend) == pytest.approx(paper, rel=1e-6)
    assert _gain(state, prob, backend, GainSensor(0.0, 50.0)) == pytest.approx(paper, rel=1e-6)
    # minimum range 4: the return at 2 is too close, so every cell is measured only through the wall's (0.5)
    assert _gain(state, prob, backend, GainSensor(4.0, 50.0)) == pytest.approx(0.5 * 36 / PAPER_TOTAL, rel=1e-6)
    # maximum range 6: only the return at 2 (0.5) measures, and only the cells up to it
    assert _gain(state, prob, backend, GainSensor(0.0, 6.0)) == pytest.approx(0.5 * (1 + 2) / PAPER_TOTAL, rel=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_open_ray_without_a_return_counts_nothing_by_hand(backend):
    # the row is unknown with p = 0 up to the grid's border at t = 29 (past R_max = 20)
    state, prob = _row()
    assert _gain(state, prob, backend) == pytest.approx(1.0, rel=1e-6)  # the paper's: the border is occupied
    assert _gain(state, prob, backend, GainSensor(0.0, 50.0, walls=False)) == 0.0
    assert _gain(state, prob, backend, GainSensor(0.0, 50.0, walls=True)) == pytest.approx(1.0, rel=1e-6)
    assert _gain(state, prob, backend, GainSensor(0.0, 25.0, walls=True)) == 0.0  # the wall beyond the range


@pytest.mark.parametrize("backend", BACKENDS)
def test_grazing_incidence_has_no_return_by_hand(backend):
    # a half-space wall x >= 6 (normal along x); the ray 80 degrees off the normal meets it
    angle = math.radians(80.0)
    b = np.array([[math.cos(angle), math.sin(angle)]])
    state = np.full((12, 80), -1, dtype=np.int8)
    state[6:] = 1
    state[1, 2] = 0
    prob = np.zeros(state.shape, dtype=np.float32)
    t = np.arange(41)
    cells = np.array([1, 2]) + np.floor(t[:, None] * b + 0.5).astype(int)
    wall = int(np.argmax(cells[:, 0] >= 6))  # first sample in the wall
    assert 0 < wall <= 40 and np.all(cells[:wall, 1] < 80)
    paper = sum(range(1, wall)) / sum(range(41))

    def gain(sensor):
        settings = GainSettings(sensor=sensor)
        return float(ray_gains(state, prob, b, 40, np.array([[1, 2]]), backend, settings=settings)[0, 0])

    assert gain(None) == pytest.approx(paper, rel=1e-6)
    assert gain(GainSensor(0.0, 100.0, grazing_deg=85.0)) == pytest.approx(paper, rel=1e-6)
    assert gain(GainSensor(0.0, 100.0, grazing_deg=75.0)) == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_exact_sampling_weighs_entry_distances_by_hand(backend):
    # along +x from a cell centre, cell 1 + k is entered at k - 0.5; weights (k - 0.5) for entries
    # <= 20 (k = 1..20), normalised per ray: 200; unknown k = 1..8, the wall at k = 9
    state, prob = _row()
    state[10, 1] = 1
    expected = sum(k - 0.5 for k in range(1, 9)) / sum(k - 0.5 for k in range(1, 21))
    assert _gain(state, prob, backend, sampling="exact") == pytest.approx(expected, rel=1e-6)
    assert _gain(state, prob, backend, GainSensor(0.0, 50.0), "exact") == pytest.approx(expected, rel=1e-6)
    assert _gain(state, prob, backend, GainSensor(12.0, 50.0), "exact") == 0.0


def _slow_traversal(direction: np.ndarray, limit: float) -> list[tuple[int, ...]]:
    """The cells a ray from the centre of cell 0 crosses with positive length, entered within
    ``limit``, in order: every cell of the bounding box against the ray by the slab test."""
    dims = direction.size
    reach = int(math.ceil(limit)) + 1
    found = []
    for cell in np.ndindex(*(2 * reach + 1,) * dims):
        c = np.array(cell) - reach
        low, high = c - 0.5, c + 0.5
        with np.errstate(divide="ignore"):
            t1, t2 = low / direction, high / direction
        t_near = np.max(np.minimum(t1, t2))
        t_far = np.min(np.maximum(t1, t2))
        t_near = max(t_near, 0.0)
        if t_far > t_near and t_near <= limit:
            found.append((t_near, tuple(int(v) for v in c)))
    return [cell for _, cell in sorted(found)]


@pytest.mark.parametrize("dims", [2, 3])
def test_exact_traversal_visits_the_cells_of_a_slow_traversal(dims):
    rng = np.random.default_rng(7 + dims)
    directions = rng.normal(size=(12, dims))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    limit = 9.0 if dims == 3 else 25.0
    offsets, distance, counts = traversal_table(directions, limit)
    for h in range(directions.shape[0]):
        table = [tuple(int(v) for v in offsets[h, k]) for k in range(counts[h])]
        assert table == _slow_traversal(directions[h], limit)
        assert np.all(np.diff(distance[h, : counts[h]]) > 0)
        steps = np.abs(np.diff(offsets[h, : counts[h]].astype(int), axis=0))
        assert np.all(steps.sum(axis=1) == 1)  # one cell along one axis per step


def test_traversal_tables_are_kept_read_only_per_directions_and_limit():
    directions = np.array([[0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    first = traversal_table(directions, 9.0)
    assert traversal_table(directions.copy(), 9.0)[0] is first[0]  # the same rays: the kept table
    assert all(not table.flags.writeable for table in first)
    longer = traversal_table(directions, 12.0)
    assert longer[2][1] == 13 and first[2][1] == 10  # straight up: the cells entered within the limit
    other = traversal_table(directions[::-1], 9.0)
    np.testing.assert_array_equal(other[0][0, : other[2][0]], np.array([[0, 0, k] for k in range(10)]))


def _random_grid(rng, shape):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[0.45, 0.5, 0.05])
    state[tuple(slice(2, 9) for _ in shape)] = 0  # an empty block: origins whose first samples are skipped
    prob = (rng.random(shape) * 0.4).astype(np.float32)
    return state, prob


SENSORS = [None, GainSensor(3.0, 25.0, 75.0, True), GainSensor(2.0, 30.0, 70.0, False), GainSensor(0.0, 12.0)]


@pytest.mark.parametrize("dims,shape,n_rays", [(2, (40, 34), 8), (3, (18, 16, 14), 4)])
@pytest.mark.parametrize("sampling", ["rounded", "exact"])
def test_kernel_matches_reference(dims, shape, n_rays, sampling):
    rng = np.random.default_rng(dims * 10 + len(sampling))
    state, prob = _random_grid(rng, shape)
    d = ray_directions(dims, n_rays)
    member = view_membership(d, orientations(dims), 60.0, 46.0 if dims == 3 else None)
    origins = np.argwhere(state == 0)[::3][:120]
    for sensor in SENSORS:
        for mode in ("prob", "ig"):
            settings = GainSettings(mode=mode, sensor=sensor, sampling=sampling)
            ref = origin_view_gains(state, prob, d, 16, member, origins, "numpy", settings=settings)
            cl = origin_view_gains(state, prob, d, 16, member, origins, "opencl", settings=settings)
            np.testing.assert_allclose(cl, ref, rtol=2e-5, atol=2e-6)
            rays = ray_gains(state, prob, d, 16, origins, "opencl", settings=settings)
            np.testing.assert_allclose(rays @ member, ref, rtol=2e-5, atol=2e-6)


@pytest.mark.parametrize("lanes", LANE_WIDTHS)
def test_every_lane_width_matches_the_reference(monkeypatch, lanes):
    import nbv_prob_cnn.gain.opencl as opencl

    caster = OpenCLRayCaster(lanes=lanes)
    # the sensor program marches at most SENSOR_MAX_LANES (a pocl build crash at 16 lanes)
    assert caster.program_lanes(sensor=True) == min(lanes, SENSOR_MAX_LANES) and caster.program_lanes() == lanes
    monkeypatch.setattr(opencl, "get_ray_caster", lambda: caster)
    rng = np.random.default_rng(3)
    state, prob = _random_grid(rng, (16, 14, 12))
    d = ray_directions(3, 4)
    member = view_membership(d, orientations(3), 60.0, 46.0)
    origins = np.argwhere(state == 0)[::4][:60]
    for sampling in ("rounded", "exact"):
        settings = GainSettings(sensor=GainSensor(2.0, 20.0, 72.0, False), sampling=sampling)
        ref = origin_view_gains(state, prob, d, 14, member, origins, "numpy", settings=settings)
        cl = origin_view_gains(state, prob, d, 14, member, origins, "opencl", settings=settings)
        np.testing.assert_allclose(cl, ref, rtol=2e-5, atol=2e-6)


@pytest.mark.parametrize("dims,shape,n_rays", [(2, (48, 40), 8), (3, (22, 20, 16), 4)])
@pytest.mark.parametrize("sampling", ["rounded", "exact"])
def test_pruned_search_finds_the_exact_argmax(monkeypatch, dims, shape, n_rays, sampling):
    bounded = []  # whether each search used block bounds (dense origins) and how many it evaluated
    original = OpenCLRayCaster.best_views

    def spy(self, *args, **kwargs):
        found = original(self, *args, first_batch=64, **kwargs)  # small batches: pruning on small grids
        bounded.append(found[3] < args[1].shape[0])
        return found

    monkeypatch.setattr(OpenCLRayCaster, "best_views", spy)
    d = ray_directions(dims, n_rays)
    member = view_membership(d, orientations(dims), 60.0, 46.0 if dims == 3 else None)
    for seed in range(2):
        rng = np.random.default_rng(100 + seed)
        state, prob = _random_grid(rng, shape)
        corner = tuple(slice(0, n // 3) for n in shape)
        state[rng.random(shape) < 0.9] = 0  # unknown space mostly in one corner: most origins are pruned
        state[corner] = np.where(rng.random(state[corner].shape) < 0.7, -1, state[corner])
        for sensor in SENSORS[:3]:
            settings = GainSettings(sensor=sensor, sampling=sampling)
            every = origin_view_gains(state, prob, d, 16, member, None, "opencl", settings=settings)
            flat = int(np.argmax(every))
            for prune_views in (True, False):
                best = best_origin_view(state, prob, d, 16, member, None, "opencl", prune_views=prune_views,
                                        settings=settings)  # fmt: skip
                index, view, gain = best
                assert (index, view) == divmod(flat, every.shape[1])
                assert gain == every.flat[flat]
    assert any(bounded)  # some searches pruned origins


def test_sensor_from_the_preset_and_bad_inputs():
    kinect = GainSensor.from_noise(sensor_noise("kinect_v1"), 0.0116, walls=False)
    assert kinect.min_range == pytest.approx(0.5 / 0.0116)
    assert kinect.max_range == pytest.approx(4.0 / 0.0116)
    assert kinect.grazing_deg == 75.0 and not kinect.walls
    with pytest.raises(ValueError, match="max_range"):
        GainSensor(5.0, 5.0)
    with pytest.raises(ValueError, match="grazing_deg"):
        GainSensor(0.0, 10.0, grazing_deg=0.0)
    with pytest.raises(ValueError, match="sampling"):
        GainSettings(sampling="dense")
    with pytest.raises(ValueError, match="paper's gain variant"):
        GainSettings(variant="original", sampling="exact")
    with pytest.raises(ValueError, match="GainSensor"):
        GainSettings(sensor=(0.0, 10.0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="needs gain_sensor"):
        PlanningContext.for_dataset("2d", sensor_model="returns")
    with pytest.raises(ValueError, match="gain_variant"):
        PlanningContext.for_dataset("2d", sampling="exact", gain_variant="original")


def test_rounded_table_is_the_papers_and_stops_at_the_range():
    d = ray_directions(3, 4)
    samples = ray_samples(d, 16, "rounded", reach=40)
    assert samples.offsets.shape[1] == 41 and samples.weighted == 17
    assert samples.total == sum(t * t for t in range(17))
    short = ray_samples(d, 16, "rounded", reach=10)
    assert short.offsets.shape[1] == 11 and short.total == samples.total  # nothing is measured past 10


def test_planner_context_passes_the_sensor_to_the_search():
    rng = np.random.default_rng(5)
    state, prob = _random_grid(rng, (40, 36))
    sensor = GainSensor(2.0, 30.0, 75.0, walls=False)
    context = PlanningContext.for_dataset("2d", backend="opencl", sensor_model="returns", gain_sensor=sensor,
                                          sampling="exact")  # fmt: skip
    origins = context.candidate_origins(state)
    choice = search_best_view(state, prob, origins, context)
    gains = origin_view_gains(state, prob, context.directions, context.active_sensor.r_max, context.membership,
                              origins, "numpy", settings=GainSettings(sensor=sensor, sampling="exact"))  # fmt: skip
    flat = int(np.argmax(gains))
    assert choice is not None and choice.gain == pytest.approx(float(gains.flat[flat]), rel=1e-5)
    assert tuple(choice.cell) == tuple(origins[flat // gains.shape[1]])


def test_explore_command_passes_the_preset_to_the_gain(tmp_path, monkeypatch):
    import argparse

    from nbv_prob_cnn.commands import explore as command

    seen = {}

    def fake_explore(world, planner, context, views, **kwargs):
        seen["context"], seen["noise"] = context, kwargs["noise"]
        raise RuntimeError("stop here")

    monkeypatch.setattr(command, "explore", fake_explore)
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    base = ["--dataset", "2d", "--log", str(tmp_path / "run.csv"), "--views", "2", "--quiet"]
    with pytest.raises(ValueError, match="needs a --noise preset"):
        command.run(parser.parse_args([*base, "--sensor-model", "returns"]))
    args = parser.parse_args([*base, "--noise", "astra", "--room-margin", "0.3", "--sensor-model", "returns",
                              "--sampling", "exact"])  # fmt: skip
    with pytest.raises(RuntimeError, match="stop here"):
        command.run(args)
    context = seen["context"]
    resolution = context.defaults.resolution_m
    assert context.sampling == "exact" and context.sensor_model == "returns"
    assert context.returns_sensor == GainSensor(0.6 / resolution, 8.0 / resolution, 72.0, walls=True)
    assert seen["noise"].name == "astra"
    plain = parser.parse_args([*base, "--noise", "kinect_v1"])  # the paper's gain unless asked
    with pytest.raises(RuntimeError, match="stop here"):
        command.run(plain)
    assert seen["context"].returns_sensor is None and not seen["context"].gain_sensor.walls
