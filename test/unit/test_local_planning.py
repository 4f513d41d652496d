"""The planners' local path on 3DT data (docs/performance.md#scale): tiles of the shipped 3DT CNN against
one whole-grid pass, and the planner's views (frontier band, CNN over the rays' reach, search on the
reach) against the dense search (every empty cell, whole-grid CNN)."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import Sensor
from nbv_prob_cnn.basics.region import check_region
from nbv_prob_cnn.completion import complete
from nbv_prob_cnn.completion.tiled import complete_region, halo_cells, plan_tiles, receptive_radius
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.planners.base import search_views


@pytest.fixture(scope="module")
def state_3dt():
    """A 3DT held-out world (seed 120) seen from 6 random views."""
    from nbv_prob_cnn.basics.camera import orientations
    from nbv_prob_cnn.basics.datasets import DATASET_SPECS
    from nbv_prob_cnn.sensing.observe import observe
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", 120)
    rng = np.random.default_rng(120)
    state = np.full(world.shape, -1, dtype=np.int8)
    free = np.argwhere(world.ground_truth == 0)
    views = orientations(3)
    for _ in range(6):
        observe(state, world.ground_truth, free[rng.integers(free.shape[0])], views[rng.integers(len(views))],
                DATASET_SPECS["3dt"].sensor)  # fmt: skip
    return state


def test_tiles_equal_whole_grid_inference_on_the_shipped_3dt_weights(state_3dt):
    """The shipped 3DT CNN on its 128×128×96 grid: several tiles (48-cell halos) equal one pass within 1e-4."""
    from nbv_prob_cnn.completion.inference import load_model

    net = load_model(dataset="3dt", device="cpu")
    assert receptive_radius(net) == 45 and halo_cells(net) == 48
    whole = complete(state_3dt, model=net, device="cpu")
    tiled = complete_region(state_3dt, model=net, device="cpu", max_window_cells=700_000)
    assert len(plan_tiles(state_3dt.shape, check_region(None, state_3dt.shape), 16, 48, 700_000)) > 1
    assert np.abs(tiled - whole).max() <= 1e-4
    one = complete_region(state_3dt, model=net, device="cpu")  # fits one window: the same call as complete()
    np.testing.assert_array_equal(one, whole)


def _same_views(got, want):
    assert len(got) == len(want) > 0
    for a, b in zip(got, want, strict=True):
        assert (tuple(a.cell), a.view_index) == (tuple(b.cell), b.view_index)
        assert a.gain == pytest.approx(b.gain, rel=1e-5)


@pytest.mark.parametrize("top_k", [1, 5])
def test_the_planner_finds_the_dense_searchs_views_on_3dt(state_3dt, top_k):
    """cnn_prob on a 3DT held-out state: the views of the dense search over every empty cell on the
    data set's stride, with the CNN over the whole grid."""
    context = PlanningContext.for_dataset("3dt", backend="opencl")
    prob = complete(state_3dt, dataset="3dt")
    dense = search_views(state_3dt, prob, context.candidate_origins(state_3dt), context, "prob", top_k,
                         probability="cnn")  # fmt: skip
    _same_views(make_planner("cnn_prob").rank(state_3dt, context, top_k), dense)


def test_a_workspace_plans_on_the_cnn_of_its_reach(state_3dt, monkeypatch):
    """A short-range sensor (40 cells) and a workspace in a corner: the CNN runs on the workspace's
    reach only, the search on that part of the grid; the views are the dense search's over the
    workspace (whole-grid CNN)."""
    sensor = Sensor(60.0, 46.0, 40)
    context = PlanningContext.for_dataset("3dt", backend="opencl", sensor=sensor)

    def workspace(origins):
        return origins[(origins[:, 0] < 24) & (origins[:, 1] < 30) & (origins[:, 2] > 20)]

    import nbv_prob_cnn.completion.tiled as tiled

    prob = complete(state_3dt, dataset="3dt")
    origins = workspace(context.candidate_origins(state_3dt))
    dense = search_views(state_3dt, prob, origins, context, "prob", 5, probability="cnn")
    windows = []
    monkeypatch.setattr(tiled, "complete", lambda s, **k: windows.append(s.shape) or complete(s, **k))
    _same_views(make_planner("cnn_prob").rank(state_3dt, context, 5, workspace), dense)
    # the reach of the workspace grown by the 48-cell halo: less than the grid on x and y
    assert len(windows) == 1 and windows[0][0] < 128 and windows[0][1] < 128
    windowed = PlanningContext.for_dataset("3dt", backend="opencl", sensor=sensor, cnn_window=16)
    found = make_planner("cnn_prob").rank(state_3dt, windowed, 5, workspace)
    assert found and all(c.cell[0] < 24 and c.cell[1] < 30 and c.cell[2] > 20 for c in found)


def test_the_cnn_window_through_hooks_equals_the_window_here(state_3dt):
    """With a completion service (the hooks of nbv_planner's remote path) the CNN window travels alone:
    the hook gets the window's grid and corner, and the ranking gets the same map as the window
    completed here, hence the same views."""
    from nbv_prob_cnn.planners.requests import rank_for_request

    sensor = Sensor(60.0, 46.0, 40)

    def workspace(origins):
        return origins[(origins[:, 0] < 24) & (origins[:, 1] < 30) & (origins[:, 2] > 20)]

    here = PlanningContext.for_dataset("3dt", backend="opencl", sensor=sensor, cnn_window=16)
    expected = make_planner("cnn_prob").rank(state_3dt, here, 5, workspace)
    sent, maps = [], []

    def service(window_state, _context, corner=None):
        sent.append((window_state.shape, corner))
        return complete(window_state, dataset="3dt")

    def ranker(name, grid, prob, top_k):
        maps.append(prob)
        server = PlanningContext.for_dataset("3dt", backend="opencl", sensor=sensor)
        return rank_for_request(name, "ig", grid, server, top_k, workspace, prob)

    remote = PlanningContext.for_dataset(
        "3dt", backend="opencl", sensor=sensor, cnn_window=16, completion=service, ranker=ranker
    )
    got = make_planner("cnn_prob").rank(state_3dt, remote, 5, workspace)  # the box: in a request, to the ranker
    assert [(tuple(c.cell), c.view_index, c.gain) for c in got] == [
        (tuple(c.cell), c.view_index, c.gain) for c in expected
    ]
    # one call with the window alone: the candidates' box (x < 24, y < 30, z > 20) grown by 16 cells
    assert len(sent) == 1
    shape, corner = sent[0]
    origins = workspace(here.candidate_origins(state_3dt))
    lo = np.maximum(origins.min(axis=0) - 16, 0)
    hi = np.minimum(origins.max(axis=0) + 17, state_3dt.shape)
    assert corner == tuple(int(v) for v in lo) and shape == tuple(int(v) for v in hi - lo)
    assert shape[0] < state_3dt.shape[0] and shape[1] < state_3dt.shape[1]
    # outside the window the unknown cells carry p0
    outside = np.ones(state_3dt.shape, dtype=bool)
    outside[tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))] = False
    unknown_outside = outside & (state_3dt == -1)
    assert unknown_outside.any() and np.all(maps[0][unknown_outside] == np.float32(here.defaults.p0))


def test_a_workspace_box_lists_its_candidates_in_its_cells_alone(state_3dt, monkeypatch):
    """A request's workspace (a box in metres) and origin budget, as nbv_planner builds them: the planner
    lists empty cells in the box's cells only, and ranks as with the same filter over every empty cell
    (the same origins, so the same random draw of the budget)."""
    from nbv_prob_cnn.basics.geometry import GridGeometry
    from nbv_prob_cnn.planners.base import BoundedFilter
    from nbv_prob_cnn.planners.recording import RecordingPlanner
    from nbv_prob_cnn.planners.requests import origin_filter

    geometry = GridGeometry((-0.2, 0.1, 0.0), 0.0116, state_3dt.shape)
    low, high = np.array([0.0, 0.3, 0.3]), np.array([0.6, 1.2, 0.9])

    def request_filter():
        return origin_filter(geometry, True, low, high, 400, np.random.default_rng(5))

    bounded = request_filter()
    assert isinstance(bounded, BoundedFilter)
    lo, hi = bounded.region
    assert hi[0] - lo[0] < state_3dt.shape[0] and hi[1] - lo[1] < state_3dt.shape[1]
    context = PlanningContext.for_dataset("3dt", backend="opencl")
    listed = []
    listing = PlanningContext.candidate_origins
    monkeypatch.setattr(
        PlanningContext,
        "candidate_origins",
        lambda self, s, region=None: listed.append(region) or listing(self, s, region),
    )
    for name in ("prob_ig", "cnn_prob"):
        expected = make_planner(name).rank(state_3dt, context, 5, request_filter().keep)  # every empty cell listed
        got = RecordingPlanner(make_planner(name), request_filter()).rank(state_3dt, context, 5)
        assert expected and all(geometry.cells_in_box(np.array([c.cell for c in got]), low, high))
        _same_views(got, expected)
    assert listed == [None, bounded.region] * 2


def test_bfloat16_completion_ranks_like_float32_on_3dt(state_3dt, bf16):
    """The opt-in bfloat16 CNN on the shipped 3DT weights: probabilities within 0.01 of float32's (measured
    0.005), the same five best views with gains within 0.1 %."""
    exact = complete(state_3dt, dataset="3dt")
    lowered = complete(state_3dt, dataset="3dt", precision="bfloat16")
    assert 0.0 < np.abs(lowered - exact).max() <= 0.01
    ranked = {}
    for precision in ("float32", "bfloat16"):
        context = PlanningContext.for_dataset("3dt", backend="opencl", cnn_precision=precision)
        ranked[precision] = make_planner("cnn_prob").rank(state_3dt, context, 5)
    got, want = ranked["bfloat16"], ranked["float32"]
    assert [(tuple(c.cell), c.view_index) for c in got] == [(tuple(c.cell), c.view_index) for c in want]
    np.testing.assert_allclose([c.gain for c in got], [c.gain for c in want], rtol=1e-3)
    with pytest.raises(ValueError, match="cnn_precision"):
        PlanningContext.for_dataset("3dt", cnn_precision="float16")
