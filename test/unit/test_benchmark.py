"""The planning benchmark's baseline kernels compute the same search as the planners' path (the
authors'-scheme kernel: the same as the original gain variant's reference)."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.bench.planning import authors_ray_terms, authors_view_search, baseline_view_search
from nbv_prob_cnn.gain import GainSettings, origin_view_gains, ray_directions, ray_gains
from nbv_prob_cnn.gain.reference import original_ray_terms
from nbv_prob_cnn.planners import PlanningContext, search_best_view

SMALL_3D = DatasetDefaults("3du", 3, (18, 16, 14), 0.01, Sensor(60.0, 46.0, 8), 4, 3)


def test_baselines_find_the_reference_best_view(rng):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=SMALL_3D.shape, p=[0.5, 0.45, 0.05])
    prob = probability_with_constant(state, 0.15)
    context = PlanningContext(SMALL_3D, backend="opencl")
    origins = np.argwhere(state == 0)
    reference = (ray_gains(state, prob, context.directions, 8, origins, "numpy") @ context.membership).ravel()
    fused = search_best_view(state, prob, origins, context)
    n_views = context.membership.shape[1]
    assert np.argmax(reference) == np.flatnonzero((origins == fused.cell).all(axis=1))[0] * n_views + fused.view_index
    gain, index, device_bytes = baseline_view_search(state, prob, origins, context, "two_step")
    assert index == np.argmax(reference) and abs(gain - reference.max()) < 1e-4
    assert device_bytes >= origins.shape[0] * context.directions.shape[0] * 4  # per-ray gains are stored
    # the naive kernel rounds a float position: the same search up to rare half-way cells
    gain, index, _ = baseline_view_search(state, prob, origins, context, "naive")
    assert abs(gain - reference.max()) < 0.05 * reference.max()


AUTHORS_CASES = [(2, (40, 36), 16, 30), (3, (18, 16, 14), 4, 14), (3, (12, 13, 11), 16, 9)]


@pytest.mark.parametrize("dims,shape,n_rays,r_max", AUTHORS_CASES)
@pytest.mark.parametrize("free_hits", [False, True])
def test_authors_scheme_kernel_matches_the_original_reference(rng, dims, shape, n_rays, r_max, free_hits):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[0.5, 0.43, 0.07])
    prob = np.where(state == -1, rng.random(shape), 0.0).astype(np.float32)
    directions = ray_directions(dims, n_rays)
    origins = np.argwhere(state == 0)
    hits, totals, _ = authors_ray_terms(state, prob, origins, directions, r_max, free_hits)
    want_hits, want_totals = original_ray_terms(state, prob, directions, r_max, origins, "prob", free_hits)
    assert want_hits.max() > 0.1
    assert np.abs(hits - want_hits).max() < 1e-5 * want_totals.max() and np.allclose(totals, want_totals, rtol=1e-6)


def test_authors_view_search_finds_the_original_best_view(rng):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=SMALL_3D.shape, p=[0.5, 0.45, 0.05])
    prob = probability_with_constant(state, 0.15)
    context = PlanningContext(SMALL_3D, backend="opencl", gain_variant="original")
    origins = np.argwhere(state == 0)
    reference = origin_view_gains(state, prob, context.directions, 8, context.membership, origins, "numpy",
                                  settings=GainSettings(variant="original")).ravel()  # fmt: skip
    gain, index, _ = authors_view_search(state, prob, origins, context, free_hits=False)
    assert index == np.argmax(reference) and abs(gain - reference.max()) < 1e-5
    pruned = search_best_view(state, prob, origins, context)
    assert pruned is not None and abs(pruned.gain - gain) < 1e-5


def test_planning_time_sweep_writes_csv_and_png(tmp_path):
    """A short timed exploration: one row per planned view, the three searches agree, the
    explored fraction grows; CSV and PNG are written."""
    from nbv_prob_cnn.bench.planning import planning_time_sweep, write_sweep

    rows = planning_time_sweep("3du", 4, 3, progress=False)
    assert len(rows) == 2 and all(r[-1] for r in rows)  # same best view in every variant
    assert 0.0 < rows[0][1] < rows[1][1] < 1.0 and all(r[2] > 0 for r in rows)
    assert all(t >= 0.0 for r in rows for t in r[3:-1])
    csv_path, png = write_sweep(rows, "test", tmp_path)
    lines = csv_path.read_text().splitlines()
    assert lines[0].startswith("view,explored_fraction,origins,pruned_wall_s") and len(lines) == 3
    assert png.stat().st_size > 1000
    sparse = planning_time_sweep("3du", 4, 5, progress=False, every=2)  # views 2 and 4 planned untimed
    assert [r[0] for r in sparse] == [1, 3] and all(r[-1] for r in sparse)


def test_the_cnn_table_shows_each_row_as_soon_as_it_is_measured(monkeypatch):
    # issue 48: `nbv bench --suite cnn` printed nothing for 37 s, then the whole table
    import types

    import nbv_prob_cnn.completion
    import nbv_prob_cnn.worlds
    from nbv_prob_cnn.bench import cnn_suite as planning

    events = []
    world = types.SimpleNamespace(shape=(4, 4))
    monkeypatch.setattr(nbv_prob_cnn.worlds, "load_or_generate", lambda d, s: events.append(("load", d)) or world)
    monkeypatch.setattr(nbv_prob_cnn.completion, "complete", lambda *a, **k: None)
    monkeypatch.setattr(planning, "_defaults", lambda d: None)
    monkeypatch.setattr(planning, "PlanningContext", lambda *a, **k: None)
    monkeypatch.setattr(planning, "half_explored", lambda w, c: None)
    monkeypatch.setattr(planning, "make_planner", lambda name: None)
    monkeypatch.setattr(planning, "_time", lambda fn, repeats: 0.25)
    text = planning.cnn_table(echo=lambda line: events.append(("echo", line)))
    echoed = [e[1] for e in events if e[0] == "echo"]
    assert "\n".join(echoed) == text and len(echoed) == 5  # header, rule, 2D, 3DU, 3DT
    assert [e[0] for e in events] == ["echo", "echo", "load", "echo", "load", "echo", "load", "echo"]
    assert events[3] == ("echo", "| 2D | 4×4 | 0.250 | 0.250 | 0.250 | 0.250 | 1.00 | 0.250 | 1.00 |")
    assert planning.cnn_table() == text  # without echo: the same table, printed by nobody


def test_exploration_plan_table_sums_each_methods_best_time_per_view(monkeypatch):
    """Per data set, the mean over the views of each method's best time on the grid before each view,
    and the ratios; the exploration follows cnn_surface's views and ends when it has none. A fake clock:
    each cnn_prob plan takes 0.2 s (CPU 0.4), each cnn_surface plan 0.3 s (CPU 0.5), the first repeat
    of each view 1 s longer (best of 2 drops it); one warm-up plan per method before the first view."""
    import types

    import nbv_prob_cnn.worlds
    from nbv_prob_cnn.bench import cnn_suite
    from nbv_prob_cnn.planners.base import ViewChoice

    clock = {"wall": 0.0, "cpu": 0.0}
    fake_time = types.SimpleNamespace(perf_counter=lambda: clock["wall"], process_time=lambda: clock["cpu"])
    monkeypatch.setattr(cnn_suite, "time", fake_time)

    class FakePlanner:  # one per method and data set
        def __init__(self, name: str) -> None:
            self.name, self.calls = name, 0

        def plan(self, state, context):
            self.calls += 1  # a warm-up before the first view, then 2 repeats per view
            slow = 1.0 if self.calls > 1 and self.calls % 2 == 0 else 0.0  # each view's first repeat
            clock["wall"] += (0.2 if self.name == "cnn_prob" else 0.3) + slow
            clock["cpu"] += (0.4 if self.name == "cnn_prob" else 0.5) + slow
            planned = (self.calls - 1) // 2  # views planned so far
            if self.name == "cnn_surface" and state.ndim == 3 and planned >= 2:
                return None  # 3D: nothing left after the second view
            return ViewChoice(np.array([1] * state.ndim), 0, 1.0)

    world2 = types.SimpleNamespace(shape=(6, 5), ground_truth=np.zeros((6, 5), np.int8))
    world3 = types.SimpleNamespace(shape=(4, 4, 4), ground_truth=np.zeros((4, 4, 4), np.int8))
    monkeypatch.setattr(nbv_prob_cnn.worlds, "load_or_generate", lambda d, s: world2 if d == "2d" else world3)
    monkeypatch.setattr(cnn_suite, "make_planner", FakePlanner)
    monkeypatch.setattr(cnn_suite, "observe", lambda *a: None)
    text = cnn_suite.exploration_plan_table(repeats=2, views=3, progress=False)
    rows = text.splitlines()[2:]
    assert rows[0] == "| 2D | 3 | 0.200 | 0.300 | 1.50 | 0.400 | 0.500 | 1.25 |"
    assert rows[1].startswith("| 3DU | 2 | 0.200 | 0.300 | 1.50 |")  # 3D: stopped after the second view
    assert rows[2].startswith("| 3DT | 2 |")
