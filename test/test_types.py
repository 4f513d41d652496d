"""Static checks: mypy on the typed core modules (a failing check names file and line), and the
mode Literals match the values the code accepts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Core modules under mypy; add a module here once it passes.
TYPED = [
    "nbv_prob_cnn/modes.py",
    "nbv_prob_cnn/sensor_noise.py",
    "nbv_prob_cnn/observe.py",
    "nbv_prob_cnn/grid.py",
    "nbv_prob_cnn/geometry.py",
    "nbv_prob_cnn/planners/methods.py",
    "nbv_prob_cnn/visualize_run.py",
    "nbv_prob_cnn/perception/messages.py",
    "nbv_prob_cnn/perception/bags.py",
    "nbv_prob_cnn/ros/names.py",
    "nbv_prob_cnn/ros/graph.py",
]


def test_mypy_on_the_typed_core():
    pytest.importorskip("mypy")
    run = subprocess.run(
        [sys.executable, "-m", "mypy", "--ignore-missing-imports", "--follow-imports=silent",
         "--no-error-summary", *TYPED],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr


def test_mode_literals_match_the_accepted_values():
    from nbv_prob_cnn.gain import BACKENDS
    from nbv_prob_cnn.modes import BACKEND_NAMES, GAIN_MODES, PROBABILITY_SOURCES
    from nbv_prob_cnn.planners.methods import GAIN_METHODS

    assert tuple(BACKENDS) == BACKEND_NAMES
    assert {m.mode for m in GAIN_METHODS.values()} == set(GAIN_MODES)
    assert {m.probability for m in GAIN_METHODS.values()} - {None} == set(PROBABILITY_SOURCES)
