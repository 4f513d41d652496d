"""Exploration protocol (docs/method.md#exploration-protocol-and-metrics) and the planners' ordering on small worlds."""

import csv

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.exploration.explore import CSV_COLUMNS, explore, write_csv
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.worlds.world import World

SMALL_2D = DatasetDefaults("2d", 2, (72, 72), 1.0, Sensor(60.0, None, 28), 16, 6)
SMALL_3D = DatasetDefaults("3du", 3, (28, 28, 28), 0.01, Sensor(60.0, 46.0, 14), 4, 3)


def _box_world(defaults: DatasetDefaults, seed: int, n_boxes: int) -> World:
    """Random axis-aligned boxes: a stand-in world with occlusions (independent of the generators)."""
    rng = np.random.default_rng(seed)
    truth = np.zeros(defaults.shape, dtype=np.uint8)
    for _ in range(n_boxes):
        lo = [rng.integers(0, n - 4) for n in defaults.shape]
        size = [rng.integers(2, max(3, n // 5)) for n in defaults.shape]
        truth[tuple(slice(a, a + s) for a, s in zip(lo, size, strict=True))] = 1
    return World(defaults.name, seed, 0, truth, defaults.resolution_m, np.zeros(defaults.dims))


def _final_unknown(defaults, world, method, views, seed):
    context = PlanningContext(defaults, rng=np.random.default_rng(seed), ground_truth=world.ground_truth)
    return explore(world, make_planner(method), context, views, progress=False)


@pytest.mark.parametrize("defaults,n_boxes", [(SMALL_2D, 14), (SMALL_3D, 10)])
def test_gain_methods_beat_random(defaults, n_boxes):
    seeds = [1, 2, 3]
    finals = {m: [] for m in ("random", "prob_ig", "omniscient")}
    for seed in seeds:
        world = _box_world(defaults, seed, n_boxes)
        for method in finals:
            result = _final_unknown(defaults, world, method, 15, seed)
            finals[method].append(result.records[-1].unknown_fraction)
    mean = {m: float(np.mean(v)) for m, v in finals.items()}
    assert mean["prob_ig"] < mean["random"], mean
    assert mean["omniscient"] < mean["random"], mean
    assert mean["omniscient"] <= mean["prob_ig"], mean


def test_run_log_and_csv(tmp_path):
    world = _box_world(SMALL_3D, 7, 8)
    result = _final_unknown(SMALL_3D, world, "prob_ig", 6, 7)
    records = result.records
    assert len(records) == 6
    fractions = [r.unknown_fraction for r in records]
    assert all(b <= a for a, b in zip(fractions, fractions[1:], strict=False))
    assert np.isnan(records[0].gain) and all(r.gain > 0 for r in records[1:])
    for r in records:
        assert world.ground_truth[tuple(r.cell)] == 0  # every view is placed in empty space
        np.testing.assert_allclose(np.linalg.norm(r.quaternion), 1.0)
        np.testing.assert_allclose(r.position_m, (r.cell + 0.5) * world.resolution)
    # the state agrees with the ground truth wherever it is known
    known = result.state != -1
    np.testing.assert_array_equal(result.state[known], world.ground_truth[known])
    path = tmp_path / "run.csv"
    write_csv(records, path)
    with open(path) as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == CSV_COLUMNS
    assert len(rows) == 7 and float(rows[-1][1]) == pytest.approx(fractions[-1], abs=1e-6)


def test_run_stops_when_nothing_left_to_see():
    truth = np.zeros((12, 12), dtype=np.uint8)
    world = World("2d", 0, 0, truth, 1.0, np.zeros(2))
    result = _final_unknown(SMALL_2D, world, "prob_ig", 50, 0)
    assert result.records[-1].unknown_fraction == 0.0
    assert len(result.records) < 50 and "no view with positive gain" in result.stop_reason


def test_unknown_method():
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        make_planner("nope")


def test_omniscient_requires_ground_truth():
    world = _box_world(SMALL_2D, 1, 3)
    context = PlanningContext(SMALL_2D)
    state = np.full(world.shape, -1, dtype=np.int8)
    state[30:40, 30:40] = 0
    with pytest.raises(ValueError, match="ground truth"):
        make_planner("omniscient").plan(state, context)


def test_explore_command_passes_the_surface_options_to_the_context(tmp_path, monkeypatch, capsys):
    """``nbv explore --surface-blend B --image-rerank K`` plan with that blend and re-ranking (without
    them: the context's defaults); a negative or non-integer ``--image-rerank`` is refused naming the flag."""
    import argparse

    from nbv_prob_cnn.cli import main
    from nbv_prob_cnn.commands import explore as command
    from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND
    from nbv_prob_cnn.planners.base import DEFAULT_IMAGE_RERANK

    contexts = []

    def fake_explore(world, planner, context, views, **kwargs):
        contexts.append(context)
        raise RuntimeError("stop here")

    monkeypatch.setattr(command, "explore", fake_explore)
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    base = ["--dataset", "2d", "--method", "prob_surface", "--log", str(tmp_path / "run.csv"), "--quiet"]
    for extra, blend, rerank in [
        ([], DEFAULT_SURFACE_BLEND, DEFAULT_IMAGE_RERANK),
        (["--image-rerank", "0"], DEFAULT_SURFACE_BLEND, 0),
        (["--image-rerank", "7", "--surface-blend", "0.25"], 0.25, 7),
    ]:
        with pytest.raises(RuntimeError, match="stop here"):
            command.run(parser.parse_args(base + extra))
        assert (contexts[-1].surface_blend, contexts[-1].image_rerank) == (blend, rerank), extra
    assert DEFAULT_IMAGE_RERANK not in (0, 7)  # the flag, not the default, gave 0 and 7
    for bad in ("-1", "2.5", "many"):
        with pytest.raises(SystemExit) as exit_info:
            main(["explore", *base, "--image-rerank", bad])
        assert exit_info.value.code == 2
        assert f"argument --image-rerank: expected a number of views >= 0 (0: no re-ranking), got '{bad}'" in (
            capsys.readouterr().err
        )
    assert len(contexts) == 3  # nothing explored with a refused value
