"""The cell ranking study (studies.city_cell_ranking) on hand-built examples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.completion.data import crop_box
from nbv_prob_cnn.completion.tasks import Example

METHODS = ("flat_city_cnn", "b_city_cnn", "d_city_cnn")


def test_cell_ranking_features_and_fit_by_hand():
    """A 2D Flat City-CNN target whose cells' best view gains grow with the height axis: ρ 1
    with height, ρ -1 with the not-empty share when the unknown lies at the low end; an oracle
    network ranks cells and pairs perfectly on 'training' and 'validation' examples alike."""
    from studies.city_cell_ranking import feature_rank_agreement, fit_and_generalisation

    spec = dataset_spec("2d")
    inputs = np.zeros((2, 1, 6), np.float32)
    inputs[0, 0, 1:] = 1.0  # cell 0 unknown, cells 1..5 empty
    inputs[1, 0, 0] = 1.0  # cell 0 is the frontier
    target = np.zeros((60, 1, 6), np.float32)
    target[0, 0, 1:] = [0.1, 0.2, 0.3, 0.4, 0.5]  # best view gain grows with the last axis
    target[7, 0, 1:] = 0.05
    example = Example(inputs, target, np.ones((1, 1, 6), np.float32))
    rho = feature_rank_agreement("flat_city_cnn", spec, [example])
    assert rho["height"] == pytest.approx(1.0)
    assert rho["distance to frontier"] == pytest.approx(1.0)
    assert rho["not-empty share r8"] != rho["not-empty share r8"]  # the one unknown cell is in every cube: no ρ
    table = {example.inputs.tobytes(): target}

    class Oracle(torch.nn.Module):
        def forward(self, x):
            return torch.as_tensor(table[x[0].numpy().tobytes()])[None]

    fit = fit_and_generalisation(Oracle(), "flat_city_cnn", spec, lambda i, rng: example, 2, [example])
    assert (fit.train_cell_rho, fit.validation_cell_rho) == (pytest.approx(1.0), pytest.approx(1.0))
    assert fit.train_rho == pytest.approx(1.0) and fit.train_examples == 2


def test_inside_crop_targets_against_whole_grid_targets():
    """A 2D map twice the crop's height. With every unknown cell inside the box the crop takes,
    no ray finds unknown cells outside it: whole-grid and inside-crop targets rank alike (ρ 1).
    With an unknown block just outside the box, the whole-grid targets of the cells facing it
    grow and the rankings part (ρ < 1)."""
    from nbv_prob_cnn.completion.data import TrainingSample
    from studies.city_cell_ranking import inside_crop_agreement

    spec = dataset_spec("2d")
    box = crop_box((512, 256), spec.training.crop, np.random.default_rng(0), 1)  # the box the function draws
    rows = range(box[0].start, box[0].stop)
    truth = np.zeros((512, 256), np.uint8)
    truth[::37, ::29] = 1
    state = np.where(truth == 1, 1, 0).astype(np.int8)
    state[rows.start + 40 : rows.start + 90, 60:200] = -1
    state[rows.start + 150 : rows.start + 170, 20:40] = -1

    def agreement(state: np.ndarray) -> tuple[float, float, int]:
        sample = TrainingSample("2d", 0, state, truth, 1, np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
        return inside_crop_agreement("flat_city_cnn", spec, [sample], 1, seed=0)

    assert agreement(state) == (pytest.approx(1.0), pytest.approx(1.0), 1)
    outside = state.copy()
    edge = rows.stop if rows.stop + 60 <= 512 else rows.start - 60
    outside[edge : edge + 60, :] = -1  # a band of unknown cells beyond one edge of the box
    cell, pair, _ = agreement(outside)
    assert cell < 0.99 and pair < 0.99


def test_planner_rank_agreement_is_one_when_the_prior_is_the_truth():
    """prob_ig with P0 = 0 on a map whose unknown cells are all empty in truth computes the
    omniscient gains themselves: ρ 1 per cell and per pair; walls hidden in the unknown part
    make the two differ."""
    from nbv_prob_cnn.completion.data import TrainingSample
    from studies.city_cell_ranking import planner_rank_agreement

    spec = dataclasses.replace(dataset_spec("2d"), p0=0.0)
    truth = np.zeros((64, 64), np.uint8)
    truth[0, :] = truth[-1, :] = truth[:, 0] = truth[:, -1] = 1
    state = np.where(truth == 1, 1, 0).astype(np.int8)
    state[30:50, 10:40] = -1
    state[5:12, 45:60] = -1

    def agreement(truth: np.ndarray) -> tuple[float, float]:
        sample = TrainingSample("2d", 0, state, truth, 1, np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
        return planner_rank_agreement(spec, [sample], ("prob_ig",))["prob_ig"]

    assert agreement(truth) == (pytest.approx(1.0), pytest.approx(1.0))
    walled = truth.copy()
    walled[30:50:3, 10:40] = 1  # occupied rows inside the first unknown block
    cell, pair = agreement(walled)
    assert cell < 0.99 and pair < 0.99
