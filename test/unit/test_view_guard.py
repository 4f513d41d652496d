"""The view guard: a pose whose view changed (almost) nothing is ruled out, and never planned again."""

import csv
import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.exploration.explore import CSV_COLUMNS, explore, write_csv
from nbv_prob_cnn.exploration.view_guard import ViewGuard, default_min_changed_cells, view_key
from nbv_prob_cnn.gain import empty_origins, origin_view_gains
from nbv_prob_cnn.planners import PlanningContext, ViewChoice, make_planner
from nbv_prob_cnn.worlds.world import World

SMALL_2D = DatasetDefaults("2d", 2, (48, 48), 1.0, Sensor(60.0, None, 28), 16, 6)


def _pocket_world() -> World:
    """A thin (8-connected) anti-diagonal wall closes off the corner at (0, 0): the exact sensor
    never sees behind it, the rounded ray samples (docs/method.md#probabilistic-ray-casting-gain)
    slip between its cells."""
    truth = np.zeros(SMALL_2D.shape, dtype=np.uint8)
    x = np.arange(41)
    truth[x, 40 - x] = 1
    return World("2d", 0, 0, truth, 1.0, np.zeros(2))


def _run(world, guard, views=30, planner="prob_ig", first=None):
    context = PlanningContext(SMALL_2D, rng=np.random.default_rng(3), ground_truth=world.ground_truth, backend="numpy")
    planner = make_planner(planner) if isinstance(planner, str) else planner
    return explore(world, planner, context, views, progress=False, guard=guard, first=first)


def test_plain_loop_repeats_a_view_that_adds_nothing_and_the_guard_does_not(tmp_path):
    world = _pocket_world()
    n_cells = world.ground_truth.size
    plain = _run(world, None)
    keys = [(tuple(r.cell), r.quaternion.tobytes()) for r in plain.records]
    repeats = [i for i in range(1, len(keys)) if keys[i] == keys[i - 1] and plain.records[i].changed_cells == 0]
    assert len(repeats) >= 10  # the paper's loop takes the pocket view again and again
    assert all(r.ruled_out_views == 0 for r in plain.records)

    guard = ViewGuard(1)
    guarded = _run(world, guard)
    records = guarded.records
    # changed_cells, by the unknown fraction of all cells (an exact sensor only adds known cells)
    fractions = [1.0] + [r.unknown_fraction_all for r in records]
    for i, r in enumerate(records):
        assert r.changed_cells == round((fractions[i] - fractions[i + 1]) * n_cells)
    # a pose is ruled out by a view that changed nothing, and never taken after that
    ruled_out: set = set()
    for r in records:
        key = (tuple(int(c) for c in r.cell), r.quaternion.tobytes())
        assert key not in ruled_out
        if r.changed_cells < 1:
            ruled_out.add(key)
        assert r.ruled_out_views == len(ruled_out)
    assert len(ruled_out) >= 10 and len(guard.ruled_out) == len(ruled_out)
    # the guarded run explores at least as much as the plain one
    assert records[-1].unknown_fraction <= plain.records[-1].unknown_fraction
    path = tmp_path / "run.csv"
    write_csv(records, path)
    with open(path) as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == CSV_COLUMNS
    assert [int(row["ruled_out_views"]) for row in rows] == [r.ruled_out_views for r in records]
    assert [int(row["changed_cells"]) for row in rows] == [r.changed_cells for r in records]


class FixedRanking:
    """A hand-made 'planner': always the same two views, with made-up positive gains."""

    name = "fixed"

    def __init__(self, views):
        self.views = views

    def rank(self, state, context, top_k=1, origin_filter=None):
        return [ViewChoice(np.array(cell), view, gain) for cell, view, gain in self.views][:top_k]

    def plan(self, state, context):
        return self.rank(state, context)[0]


def test_a_view_at_a_wall_already_seen_is_ruled_out_and_the_run_stops_when_nothing_is_left():
    """A room with a wall at x = 30: the views A (at the wall, along +x) and B (along -x) each see
    something the first time and nothing the second; then no view is left."""
    truth = np.zeros(SMALL_2D.shape, dtype=np.uint8)
    truth[30, :] = 1
    world = World("2d", 0, 0, truth, 1.0, np.zeros(2))
    a, b = ((25, 24), 0, 5.0), ((25, 24), 30, 4.0)  # orientation 0: yaw 0 (+x); 30: yaw 180 deg
    planner = FixedRanking([a, b])
    first = ViewChoice(np.array(a[0]), a[1], float("nan"))
    guarded = _run(world, ViewGuard(1), views=10, planner=planner, first=first)
    taken = [(tuple(int(c) for c in r.cell), r.changed_cells, r.ruled_out_views) for r in guarded.records]
    assert [t[1] > 0 for t in taken] == [True, False, True, False]  # A, A again (nothing), B, B again
    assert [t[2] for t in taken] == [0, 1, 1, 2]
    assert guarded.stop_reason == (
        "no view with positive gain (or none feasible) after 4 views, 2 ruled out for changing < 1 cells"
    )
    plain = _run(world, None, views=10, planner=planner, first=first)
    assert len(plain.records) == 10 and all(r.changed_cells == 0 for r in plain.records[1:])


def test_gain_planner_ranking_leaves_the_ruled_out_views_out():
    """prob_ig with a ruled-out view: the guard's plan is the argmax of the numpy reference gains
    over every other (origin, orientation)."""
    rng = np.random.default_rng(5)
    state = np.full(SMALL_2D.shape, -1, dtype=np.int8)
    state[10:30, 10:30] = 0
    state[rng.random(state.shape) < 0.02] = 1
    context = PlanningContext(SMALL_2D, rng=np.random.default_rng(0), backend="numpy")
    planner = make_planner("prob_ig")
    best = planner.plan(state, context)
    guard = ViewGuard(1)
    guard.ruled_out.add(view_key(best))
    origins = empty_origins(state, 1)
    gains = origin_view_gains(
        state, probability_with_constant(state, SMALL_2D.p0), context.directions, SMALL_2D.sensor.r_max,
        context.membership, origins, "numpy",
    )  # fmt: skip
    row = int(np.flatnonzero(np.all(origins == best.cell, axis=1))[0])
    assert gains[row, best.view_index] == pytest.approx(gains.max(), rel=1e-5)
    gains[row, best.view_index] = -1.0
    flat = int(np.argmax(gains))
    second = guard.plan(planner, state, context)
    assert second is not None and view_key(second) not in guard.ruled_out
    assert second.gain == pytest.approx(gains.flat[flat], rel=1e-5)
    # the ranking of a planner without a view mask (random) also never returns a ruled-out view
    random_planner = make_planner("random")
    for choice in guard.rank(random_planner, state, context, top_k=5):
        assert view_key(choice) not in guard.ruled_out


def test_thresholds_and_bad_input():
    assert default_min_changed_cells((128, 128, 96)) == math.ceil(5e-5 * 128 * 128 * 96) == 79
    assert default_min_changed_cells((4, 4)) == 1
    assert ViewGuard.for_grid((400, 400)).min_changed_cells == 8
    guard = ViewGuard(10)
    choice = ViewChoice(np.array([1, 2]), 3, 1.0)
    assert not guard.record(choice, 10) and guard.record(choice, 9) and guard.ruled_out == {((1, 2), 3)}
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="min_changed_cells"):
            ViewGuard(bad)


def test_a_first_view_that_sees_nothing_is_followed_by_a_random_one():
    """A noisy first view facing a wall inside the sensor's minimum range returns nothing: no cell
    is known empty, so the next view is random (gain NaN) instead of the run stopping."""
    from nbv_prob_cnn.sensing.sensor_noise import SensorNoise

    truth = np.zeros(SMALL_2D.shape, dtype=np.uint8)
    truth[27:, :] = 1  # a wall 2 cells (2 m) in front of the first view
    world = World("2d", 0, 0, truth, 1.0, np.zeros(2))
    near_blind = SensorNoise("near_blind", min_range_m=5.0)
    context = PlanningContext(SMALL_2D, rng=np.random.default_rng(4), ground_truth=truth, backend="numpy")
    first = ViewChoice(np.array([25, 24]), 0, float("nan"))  # looking along +x at the wall
    result = explore(world, make_planner("prob_ig"), context, 6, progress=False, noise=near_blind, first=first,
                     guard=ViewGuard(1))  # fmt: skip
    records = result.records
    assert records[0].changed_cells == 0 and records[0].unknown_fraction_all == 1.0
    unknown_before = [1.0] + [r.unknown_fraction_all for r in records]
    for i, r in enumerate(records[1:], start=1):
        assert math.isnan(r.gain) == (unknown_before[i] == 1.0)  # random exactly while nothing is known
    assert len(records) == 6 and records[-1].unknown_fraction_all < 1.0
