"""Gains over each view's own image rays (planners/image_rays.py): the one cropped OpenCL cast
against one numpy-reference cast per view on the whole grid, and the surface methods'
re-ranking of the search's best views by them."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.gain import ray_gains
from nbv_prob_cnn.gain.frustum_rays import frustum_rays
from nbv_prob_cnn.gain.sampling import GainSensor
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.planners.base import search_views
from nbv_prob_cnn.planners.image_rays import camera_rotation, image_ray_gains, rerank_by_image

SMALL_3D = DatasetDefaults("3du", 3, (26, 24, 20), 0.05, Sensor(60.0, 46.0, 9), 4, 3)
SMALL_2D = DatasetDefaults("2d", 2, (48, 44), 0.5, Sensor(60.0, None, 15), 16, 6)


def _grid(rng: np.random.Generator, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Unknown space with an explored box and a few occupied blocks; CNN-like probabilities."""
    state = np.full(shape, -1, dtype=np.int8)
    state[tuple(slice(2, int(0.55 * s)) for s in shape)] = 0
    for _ in range(5):
        lo = [int(rng.integers(0, s - 3)) for s in shape]
        state[tuple(slice(a, a + 3) for a in lo)] = 1
    prob = np.where(state == -1, rng.uniform(0.02, 0.98, shape), (state == 1).astype(float)).astype(np.float32)
    return state, prob


def _reference(state, prob, cells, orientations, context, settings, across) -> np.ndarray:
    """One numpy-reference cast per view, on the whole grid: ``sum_r weight_r G_r``."""
    sensor = context.active_sensor
    directions, weights = frustum_rays(state.ndim, across, sensor.hfov_deg, sensor.vfov_deg)
    return np.array([
        ray_gains(state, prob, directions @ camera_rotation(o).T, sensor.r_max, cell[None], "numpy",
                  settings=settings)[0].astype(np.float64) @ weights
        for cell, o in zip(cells, orientations, strict=True)
    ])  # fmt: skip


MODELS = {
    "paper": {},
    "exact": {"sampling": "exact"},
    "returns": {"sensor_model": "returns", "gain_sensor": GainSensor(1.5, 8.0, 70.0, walls=False)},
    "returns_walls": {"sensor_model": "returns", "gain_sensor": GainSensor(1.5, 8.0, 70.0, walls=True)},
}


@pytest.mark.parametrize("defaults", [SMALL_3D, SMALL_2D], ids=["3d", "2d"])
@pytest.mark.parametrize("surface", [False, True])
@pytest.mark.parametrize("model", list(MODELS))
def test_one_cast_equals_one_reference_cast_per_view(rng, defaults, surface, model):
    state, prob = _grid(rng, defaults.shape)
    context = PlanningContext(defaults, backend="opencl", **MODELS[model])
    settings = context.gain_settings("prob", "cnn", surface)
    empty = np.argwhere(state == 0)
    count = 21
    cells = empty[rng.choice(empty.shape[0], count, replace=False)]
    orientations = context.orientations[rng.integers(0, context.orientations.shape[0], count)]
    gains = image_ray_gains(state, prob, cells, orientations, context, settings, across=6)
    expected = _reference(state, prob, cells, orientations, context, settings, 6)
    assert np.count_nonzero(expected) > count // 2
    np.testing.assert_allclose(gains, expected, rtol=1e-5, atol=1e-7)


def test_rerank_orders_by_the_image_gain_and_drops_views_without_one(rng):
    state, prob = _grid(rng, SMALL_3D.shape)
    context = PlanningContext(SMALL_3D, backend="opencl")
    settings = context.gain_settings("prob", "cnn", True)
    found = search_views(state, prob, np.argwhere(state == 0), context, top_k=12, probability="cnn", surface=True)
    found.append(type(found[0])(np.array([1, 1, 1]), 0, 0.5))  # in the occupied-free corner: sees nothing unknown
    state[0:4, 0:4, 0:4] = 1
    state[1, 1, 1] = 0
    search_gains = [c.gain for c in found]
    ranked = rerank_by_image(state, prob, list(found), context, settings, across=8)
    cells = np.array([c.cell for c in found])
    expected = _reference(state, prob, cells, context.orientations[[c.view_index for c in found]], context,
                          settings, 8)  # fmt: skip
    assert expected[-1] == 0.0
    order = [i for i in np.argsort(-expected, kind="stable") if expected[i] > 0]
    assert [id(c) for c in ranked] == [id(found[i]) for i in order]
    assert [c.gain for c in found] == search_gains  # the search gains are kept
    np.testing.assert_allclose([c.image_gain for c in found], expected, rtol=1e-5, atol=1e-7)


def test_surface_methods_take_the_best_image_gain_among_the_search_top(rng):
    """``prob_surface`` (a constant map: no CNN) with ``image_rerank`` 8 plans the view of the search's best 8
    whose image rays gain most; with 0 the search's best; ``prob_ig`` ignores the setting."""
    state, _ = _grid(rng, SMALL_3D.shape)
    origins = np.argwhere(state == 0)
    plain = PlanningContext(SMALL_3D, backend="opencl", image_rerank=0)
    reranked = PlanningContext(SMALL_3D, backend="opencl", image_rerank=8)
    prob = probability_with_constant(state, SMALL_3D.p0)
    top = search_views(state, prob, origins, plain, top_k=8, probability="constant", surface=True)
    settings = plain.gain_settings("prob", "constant", True)
    image = _reference(state, prob, np.array([c.cell for c in top]), plain.orientations[[c.view_index for c in top]],
                       plain, settings, 32)  # fmt: skip
    best = top[int(np.argmax(image))]
    planner = make_planner("prob_surface")
    chosen = planner.plan(state, reranked)
    assert (tuple(chosen.cell), chosen.view_index) == (tuple(best.cell), best.view_index)
    assert chosen.image_gain == pytest.approx(image.max(), rel=1e-5)
    first = planner.plan(state, plain)
    assert (tuple(first.cell), first.view_index, first.image_gain) == (tuple(top[0].cell), top[0].view_index, None)
    assert int(np.argmax(image)) != 0  # the re-ranking changed the choice on this grid
    # a longer ranking: the re-ranked best 8, then the search's order
    ranked = planner.rank(state, reranked, top_k=12)
    longer = search_views(state, prob, origins, plain, top_k=12, probability="constant", surface=True)
    cells, views = np.array([c.cell for c in top]), plain.orientations[[c.view_index for c in top]]
    cast = image_ray_gains(state, prob, cells, views, plain, settings)  # the planner's numbers (near ties)
    np.testing.assert_allclose(cast, image, rtol=1e-5)
    image_order = [top[i] for i in np.argsort(-cast, kind="stable") if cast[i] > 0]
    key = lambda c: (tuple(c.cell), c.view_index)  # noqa: E731
    assert [key(c) for c in ranked] == [key(c) for c in image_order + longer[8:]][:12]
    ig = make_planner("prob_ig")
    a, b = ig.plan(state, plain), ig.plan(state, reranked)
    assert (tuple(a.cell), a.view_index, a.image_gain) == (tuple(b.cell), b.view_index, None)


@pytest.mark.parametrize("bad", [-1, 2.5, True, "20"])
def test_bad_image_rerank_is_refused(bad):
    with pytest.raises(ValueError, match="image_rerank"):
        PlanningContext(SMALL_3D, image_rerank=bad)
