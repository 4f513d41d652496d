"""The mode Literals match the values the code accepts (mypy over the whole tree runs in
``launch_scripts/lint.sh``, before the suite)."""

from __future__ import annotations


def test_mode_literals_match_the_accepted_values():
    from nbv_prob_cnn.basics.modes import BACKEND_NAMES, GAIN_MODES, PROBABILITY_SOURCES
    from nbv_prob_cnn.gain import BACKENDS
    from nbv_prob_cnn.planners.methods import GAIN_METHODS

    assert tuple(BACKENDS) == BACKEND_NAMES
    assert {m.mode for m in GAIN_METHODS.values()} == set(GAIN_MODES)
    assert {m.probability for m in GAIN_METHODS.values()} - {None} == set(PROBABILITY_SOURCES)
