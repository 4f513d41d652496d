"""The planning benchmark's baseline kernels compute the same search as the planners' path."""

import numpy as np

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.bench.planning import baseline_view_search
from nbv_prob_cnn.gain import ray_gains
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
