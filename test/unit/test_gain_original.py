"""The ``original`` gain variant (the authors' host choices, docs/original_code.md): hand-worked
rays and views, the kernel against the numpy reference, the exact pruned search, validation."""

import functools

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.basics.grid import probability_from_truth, probability_with_constant
from nbv_prob_cnn.gain import best_origin_view, origin_view_gains, ray_directions, ray_gains, view_membership
from nbv_prob_cnn.gain.opencl import OpenCLRayCaster
from nbv_prob_cnn.gain.settings import GainSettings
from nbv_prob_cnn.gain.variant import ig_min_range, sample_count, sample_weights, uses_free_hits
from nbv_prob_cnn.planners import PlanningContext, make_planner

BACKENDS = ["numpy", "opencl"]
E, O, U = 0, 1, -1  # noqa: E741
X = np.array([[1.0, 0.0]])
ORIGINAL = GainSettings(variant="original")
ORIGINAL_FREE = GainSettings(variant="original", free_hits=True)


def _original_ig(min_range: float = 0.0) -> GainSettings:
    return GainSettings(mode="ig", min_range=min_range, variant="original")


def _row(values, probs):
    """A 2D grid of one row x = 0.. (shape (n, 1)) with ``values``/``probs``."""
    state = np.array(values, dtype=np.int8)[:, None]
    prob = np.array(probs, dtype=np.float32)[:, None]
    return state, prob


def test_range_and_weights_by_hand():
    # (1 - 2 pi / 64) = 0.90183: 24 -> 21.64, 128 -> 115.43, 12 -> 10.82 samples
    assert [sample_count("original", r) for r in (24, 128, 12)] == [21, 115, 10]
    assert [sample_count("paper", r) for r in (24, 128)] == [25, 129]
    # 2D: min(t / 8, 1); 3D: min((t / 8)^2, 1)
    assert np.allclose(sample_weights("original", 10, 2), [0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1, 1])
    assert sample_weights("original", 21, 3).sum() == pytest.approx(140 / 64 + 13)
    assert np.array_equal(sample_weights("paper", 4, 3), [0, 1, 4, 9])
    assert ig_min_range("original", 0.0) == 5.0 and ig_min_range("paper", 1.5) == 1.5
    assert uses_free_hits("original", "cnn") and uses_free_hits("original", "oracle")
    assert not uses_free_hits("original", "constant") and not uses_free_hits("paper", "cnn")


@pytest.mark.parametrize("backend", BACKENDS)
def test_probabilistic_ray_2d_by_hand(backend):
    # x: 0 (origin) 1 2 empty, 3 unknown p 0.5, 4 unknown p 0.2, 5 occupied, 6.. unknown
    state, prob = _row([E, E, E, U, U, O, U, U, U, U, U, U], [0, 0, 0, 0.5, 0.2, 1, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3])
    origin = np.array([[0, 0]])
    total = 28 / 8 + 2  # t = 0..9, weights 0, 1/8 .. 7/8, 1, 1
    paper = ray_gains(state, prob, X, 12, origin, backend)
    constant = ray_gains(state, prob, X, 12, origin, backend, settings=ORIGINAL)
    free = ray_gains(state, prob, X, 12, origin, backend, settings=ORIGINAL_FREE)
    assert paper[0, 0] == pytest.approx((3 * 1 + 4 * 0.5) / 78, abs=1e-6)  # t^1, t = 0..12
    assert constant[0, 0] == pytest.approx((0.375 * 1 + 0.5 * 0.5) / total, abs=1e-6)
    # item 3: (1 - p_t) Pr(r_t)
    assert free[0, 0] == pytest.approx((0.375 * 0.5 * 1 + 0.5 * 0.8 * 0.5) / total, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_probabilistic_ray_3d_range_and_saturation_by_hand(backend):
    # a column along +z: unknown at z 4 (p 0.25), 9 (p 0.5) and 21 (beyond the original's t = 20)
    state = np.zeros((1, 1, 30), dtype=np.int8)
    prob = np.zeros(state.shape, dtype=np.float32)
    for z, p in ((4, 0.25), (9, 0.5), (21, 0.5)):
        state[0, 0, z], prob[0, 0, z] = U, p
    z_axis, origin = np.array([[0.0, 0.0, 1.0]]), np.array([[0, 0, 0]])
    total = 140 / 64 + 13
    constant = ray_gains(state, prob, z_axis, 24, origin, backend, settings=ORIGINAL)
    free = ray_gains(state, prob, z_axis, 24, origin, backend, settings=ORIGINAL_FREE)
    # weights (4/8)^2 = 0.25 and min((9/8)^2, 1) = 1; z 21 is not sampled
    assert constant[0, 0] == pytest.approx((0.25 + 1 * 0.75) / total, abs=1e-6)
    assert free[0, 0] == pytest.approx((0.25 * 0.75 + 1 * 0.5 * 0.75) / total, abs=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_information_gain_ray_by_hand(backend):
    origin = np.array([[0, 0]])
    state, _ = _row([E, E, E, U, U, U, U, U, U, U], [0] * 10)
    # first non-empty at t = 3, inside the minimum range 5: 0.01 / (w0 + w1 + w2 + 1)
    near = ray_gains(state, None, X, 12, origin, backend, settings=_original_ig(5))
    assert near[0, 0] == pytest.approx(0.01 / 1.375, abs=1e-7)
    far = ray_gains(state, None, X, 12, origin, backend, settings=_original_ig(2))
    assert far[0, 0] == pytest.approx(0.375 / 1.375, abs=1e-6)
    blocked, _ = _row([E, E, O, U, U, U], [0] * 6)
    assert ray_gains(blocked, None, X, 12, origin, backend, settings=_original_ig())[0, 0] == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_view_gain_is_ratio_of_sums_by_hand(backend):
    # origin (0, 0); ray +x meets an unknown cell at t 6, ray +y leaves the grid unblocked (all its
    # weights count as misses: outside the grid is empty to the original), ray -x leaves at once
    state = np.zeros((10, 4), dtype=np.int8)
    state[6, 0] = U
    directions = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    member = np.array([[1, 1], [1, 0], [1, 0]], dtype=np.float32)  # view 0: all rays, view 1: +x only
    gains = origin_view_gains(state, None, directions, 12, member, np.array([[0, 0]]), backend,
                              settings=_original_ig(5))  # fmt: skip
    before = 0 + 0.125 + 0.25 + 0.375 + 0.5 + 0.625  # weights of t = 0..5
    hits, totals = 0.75, before + 1
    assert gains[0, 1] == pytest.approx(hits / totals, abs=1e-6)
    assert gains[0, 0] == pytest.approx(hits / (totals + 5.5 + 5.5), abs=1e-6)
    # probabilistic: every ray's total is the sum of the weights, so the view gain is the mean
    prob = probability_with_constant(state, 0.15)
    views = origin_view_gains(state, prob, directions, 12, member, np.array([[0, 0]]), backend, settings=ORIGINAL)
    assert views[0, 0] == pytest.approx(0.75 / (3 * 5.5), abs=1e-6) and views[0, 1] == pytest.approx(0.75 / 5.5)


def _random_case(rng, dims, shape, p_unknown=0.5):
    state = rng.choice([U, E, O], size=shape, p=[p_unknown, 0.92 - p_unknown, 0.08]).astype(np.int8)
    return state, rng.random(shape).astype(np.float32)


CASES = [(2, (37, 41), 16, 30), (3, (19, 17, 21), 4, 12), (3, (14, 16, 13), 16, 10)]
KINDS = [("prob", False), ("prob", True), ("ig", False)]


@pytest.mark.parametrize("dims,shape,n_rays,r_max", CASES)
@pytest.mark.parametrize("mode,free", KINDS)
def test_kernel_matches_reference(dims, shape, n_rays, r_max, mode, free):
    state, prob = _random_case(np.random.default_rng(dims * 100 + n_rays), dims, shape)
    directions = ray_directions(dims, n_rays)
    member = view_membership(directions, orientations(dims), 60.0, None if dims == 2 else 46.0)
    settings = GainSettings(mode=mode, min_range=5.0, variant="original", free_hits=free)
    rays = [ray_gains(state, prob, directions, r_max, backend=b, settings=settings) for b in BACKENDS]
    views = [origin_view_gains(state, prob, directions, r_max, member, backend=b, settings=settings) for b in BACKENDS]
    assert rays[0].max() > 0.0 and np.abs(rays[1] - rays[0]).max() < 2e-6
    assert np.abs(views[1] - views[0]).max() < 2e-6


@pytest.mark.parametrize("lanes", [1, 4, 16])
@pytest.mark.parametrize("mode,free", KINDS)
def test_lanes_give_the_same_original_gains(lanes, mode, free):
    from nbv_prob_cnn.gain.march import ray_march
    from nbv_prob_cnn.gain.marched_grid import encode_grid

    state, prob = _random_case(np.random.default_rng(7), 3, (15, 14, 16))
    directions = ray_directions(3, 4)
    member = view_membership(directions, orientations(3), 60.0, 46.0)
    origins = np.argwhere(state == E)
    settings = GainSettings(mode=mode, min_range=5.0, variant="original", free_hits=free)
    code = encode_grid(state, prob if mode == "prob" else None)
    caster = OpenCLRayCaster(lanes=lanes)
    got = caster.run_views(code, origins, ray_march(3, directions, 20, settings), member)
    want = origin_view_gains(state, prob, directions, 20, member, origins, "numpy", settings=settings)
    assert np.abs(got - want).max() < 2e-6


@functools.cache
def _pruned_case(dims, shape, n_rays, r_max, mode, free):
    """The grid, rays, views and settings of one pruned-search case, and its numpy reference's
    best (origin, view, gain): computed once for both ``prune_views`` (it does not depend on it)."""
    state, prob = _random_case(np.random.default_rng(3 + dims + n_rays), dims, shape, p_unknown=0.3)
    directions = ray_directions(dims, n_rays)
    member = view_membership(directions, orientations(dims), 60.0, None if dims == 2 else 46.0)
    settings = GainSettings(mode=mode, min_range=5.0, variant="original", free_hits=free)
    reference = best_origin_view(state, prob, directions, r_max, member, backend="numpy", settings=settings)
    return state, prob, directions, member, settings, reference


@pytest.mark.parametrize("dims,shape,n_rays,r_max", CASES)
@pytest.mark.parametrize("mode,free", KINDS)
@pytest.mark.parametrize("prune_views", [True, False])
def test_pruned_search_is_exact(dims, shape, n_rays, r_max, mode, free, prune_views):
    state, prob, directions, member, settings, reference = _pruned_case(dims, shape, n_rays, r_max, mode, free)
    exhaustive = origin_view_gains(state, prob, directions, r_max, member, backend="opencl", settings=settings)
    flat = int(np.argmax(exhaustive))  # the first of equal maxima, origin-major
    found = best_origin_view(state, prob, directions, r_max, member, backend="opencl", prune_views=prune_views,
                             block_size=2, settings=settings)  # fmt: skip
    assert (found[0], found[1]) == divmod(flat, exhaustive.shape[1])
    assert found[2] == exhaustive.flat[flat]
    assert reference[2] == pytest.approx(found[2], abs=2e-6)


def test_planners_use_the_context_variant():
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3du", 120)
    state = np.full(world.shape, U, dtype=np.int8)
    state[20:44, 20:44, 20:44] = np.where(world.ground_truth[20:44, 20:44, 20:44] == 0, E, U)
    for method, probability in (("prob_ig", "constant"), ("omniscient", "oracle")):
        context = PlanningContext.for_dataset("3du", ground_truth=world.ground_truth, gain_variant="original")
        choice = make_planner(method).plan(state, context)
        directions = context.directions
        if probability == "constant":
            prob = probability_with_constant(state, 0.15)
        else:
            prob = probability_from_truth(state, world.ground_truth)
        origins = context.candidate_origins(state)
        settings = GainSettings(variant="original", free_hits=probability == "oracle")
        gains = origin_view_gains(state, prob, directions, context.active_sensor.r_max, context.membership, origins,
                                  "opencl", settings=settings)  # fmt: skip
        flat = int(np.argmax(gains))
        assert choice is not None and choice.gain == gains.flat[flat]
        index, view = divmod(flat, gains.shape[1])
        assert np.array_equal(choice.cell, origins[index]) and choice.view_index == view


def test_bad_variant_and_free_hits():
    state, prob = _row([E, U, U], [0, 0.5, 0.5])
    with pytest.raises(ValueError, match="gain variant"):
        ray_gains(state, prob, X, 4, settings=GainSettings(variant="authors"))
    with pytest.raises(ValueError, match="free_hits"):
        ray_gains(state, prob, X, 4, settings=GainSettings(free_hits=True))
    with pytest.raises(ValueError, match="free_hits"):
        ray_gains(state, None, X, 4, settings=GainSettings(mode="ig", variant="original", free_hits=True))
    with pytest.raises(ValueError, match="gain variant"):
        PlanningContext.for_dataset("2d", gain_variant="Original")


def test_evaluation_runs_record_and_check_the_variant(tmp_path):
    import json

    from nbv_prob_cnn.exploration.evaluation import run_status

    path = tmp_path / "2d_prob_ig_seed120.csv"
    path.write_text("unknown_fraction\n0.9\n0.8\n0.7\n")
    path.with_suffix(".json").write_text(json.dumps({"views": 3}))  # a paper run (no key)
    assert run_status(path, 3) == "done"
    assert run_status(path, 3, gain_variant="original") == "other gain variant"
    path.with_suffix(".json").write_text(json.dumps({"views": 3, "gain_variant": "original"}))
    assert run_status(path, 3, gain_variant="original") == "done"
    assert run_status(path, 3) == "other gain variant"


@pytest.mark.parametrize("command", ["explore", "evaluate"])
def test_cli_gain_variant_option(command):
    import argparse
    import importlib

    module = importlib.import_module(f"nbv_prob_cnn.commands.{command}")
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    base = ["--dataset", "2d"] + (["--log", "run.csv"] if command == "explore" else [])
    assert parser.parse_args(base).gain_variant == "paper"
    assert parser.parse_args([*base, "--gain-variant", "original"]).gain_variant == "original"
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--gain-variant", "authors"])


def test_original_ray_sets_by_hand():
    from nbv_prob_cnn.gain.original_sets import original_rays

    rays, bins = original_rays(2)
    assert rays.shape == (256, 2)  # every cell of the 16 x 16 square, interior included
    distinct, counts = np.unique(np.round(bins, 9), axis=0, return_counts=True)
    assert distinct.shape[0] == 60 and counts.sum() == 256
    boundary = np.round(ray_directions(2, 16), 9)
    assert {tuple(b) for b in distinct} == {tuple(b) for b in boundary}
    # the corner bin (-7.5, -7.5) collects the diagonal cells (i, i), i = 0..7
    corner = np.round(np.array([-1.0, -1.0]) / np.sqrt(2.0), 9)
    assert counts[np.flatnonzero((distinct == corner).all(axis=1))[0]] == 8
    rays3, bins3 = original_rays(3)
    assert rays3.shape == (16**3 - 14**3, 3) and np.allclose(bins3, rays3)  # boundary bearings bin to themselves
    assert {tuple(r) for r in np.round(rays3, 9)} == {tuple(r) for r in np.round(ray_directions(3, 16), 9)}


def test_original_orientation_sets_by_hand():
    from nbv_prob_cnn.basics.camera import optical_axis
    from nbv_prob_cnn.gain.original_sets import original_orientations

    quats = original_orientations(3)
    assert quats.shape == (52, 4)
    axes = np.round([optical_axis(q, 3) for q in quats], 6) + 0.0  # + 0.0: no -0.0
    distinct = {tuple(a) for a in axes}
    h = np.round(np.sqrt(0.5), 6)
    horizontal = {(1.0, 0.0, 0.0), (h, h, 0.0), (0.0, 1.0, 0.0), (-h, h, 0.0), (-1.0, 0.0, 0.0), (-h, -h, 0.0),
                  (0.0, -1.0, 0.0), (h, -h, 0.0)}  # fmt: skip
    assert distinct == horizontal | {(0.0, 0.0, 1.0), (0.0, 0.0, -1.0)}  # 10 optical axes
    yaws = original_orientations(2)
    assert yaws.shape == (60,) and np.isclose(np.rad2deg(yaws).max(), 180 - np.rad2deg(np.arctan2(0.5, 7.5)))


def test_context_with_the_original_view_set_plans():
    context = PlanningContext.for_dataset("2d", view_set="original", gain_variant="original", backend="opencl")
    assert context.directions.shape == (256, 2) and context.membership.shape == (256, 60)
    state = np.full((60, 60), U, dtype=np.int8)
    state[20:40, 20:40] = E
    choice = make_planner("prob_ig").plan(state, context)
    assert choice is not None and choice.gain > 0
    with pytest.raises(ValueError, match="view_set"):
        PlanningContext.for_dataset("2d", view_set="original", n_rays=8)


@pytest.mark.parametrize("shape", [(7, 5), (5, 6, 4)])
def test_reference_samples_the_literal_cells(shape):
    """The numpy reference's gather (axis by axis, flat indices, clamped) reads every sample cell
    ``origin + offset`` as a literal per-cell lookup: its value and state inside the grid,
    ``outside`` and occupied beyond it."""
    from nbv_prob_cnn.gain.reference import _sample

    rng = np.random.default_rng(len(shape))
    state = rng.choice(np.array([U, E, O], dtype=np.int8), size=shape)
    values = rng.random(shape).astype(np.float32)
    origins = np.argwhere(np.ones(shape, dtype=bool))[::3]
    offsets = rng.integers(-6, 7, size=(13, len(shape))).astype(np.int16)
    got_values, got_state = _sample(state, values, 2.5, origins, offsets)
    assert got_values.shape == got_state.shape == (origins.shape[0], offsets.shape[0])
    n_inside = 0
    for i, origin in enumerate(origins):
        for j, offset in enumerate(offsets):
            cell = tuple(int(c) for c in origin + offset)
            inside = all(0 <= c < n for c, n in zip(cell, shape, strict=True))
            n_inside += inside
            assert got_values[i, j] == (values[cell] if inside else 2.5), (cell, shape)
            assert got_state[i, j] == (state[cell] if inside else 1), (cell, shape)
    assert 0 < n_inside < got_state.size  # both sides of the border sampled
