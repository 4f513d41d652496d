"""Shared test set-up: an isolated cache directory per test session."""

import os
import tempfile

import pytest

os.environ.setdefault("NBV_CACHE_DIR", os.path.join(tempfile.gettempdir(), "nbv_prob_cnn_test_cache"))


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)
