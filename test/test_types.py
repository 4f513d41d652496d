"""Static checks: mypy on the typed core modules (a failing check names file and line), and the
mode Literals match the values the code accepts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: The core (every module outside ``ros/``, plus rclpy-free ``ros`` helpers) is
#: type-checked; modules listed here are exempt (none now).
NOT_YET: set[str] = set()


def typed_modules() -> list[str]:
    core = [p for p in (REPO / "nbv_prob_cnn").rglob("*.py") if "ros" not in p.parts]
    names = sorted(str(p.relative_to(REPO)) for p in core)
    return [n for n in names if n not in NOT_YET] + ["nbv_prob_cnn/ros/names.py", "nbv_prob_cnn/ros/graph.py"]


@pytest.mark.slow  # ~15 s without a mypy cache
def test_mypy_on_the_core():
    pytest.importorskip("mypy")
    modules = typed_modules()
    assert len(modules) > 30 and "nbv_prob_cnn/sensing/sensor_noise.py" in modules
    run = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", *modules],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr


def test_mode_literals_match_the_accepted_values():
    from nbv_prob_cnn.basics.modes import BACKEND_NAMES, GAIN_MODES, PROBABILITY_SOURCES
    from nbv_prob_cnn.gain import BACKENDS
    from nbv_prob_cnn.planners.methods import GAIN_METHODS

    assert tuple(BACKENDS) == BACKEND_NAMES
    assert {m.mode for m in GAIN_METHODS.values()} == set(GAIN_MODES)
    assert {m.probability for m in GAIN_METHODS.values()} - {None} == set(PROBABILITY_SOURCES)
