"""The ray-casting parameters that ``gain_server`` and ``nbv_planner`` (with ``in_process``) both
declare, with one default and one set of allowed values; each node describes them in its own words
(where they apply to it)."""

from __future__ import annotations

from nbv_prob_cnn.basics.modes import BACKEND_NAMES, Backend
from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND
from nbv_prob_cnn.gain.variant import GAIN_VARIANTS
from nbv_prob_cnn.planners.base import DEFAULT_IMAGE_RERANK
from nbv_prob_cnn.ros.parameters import param

#: The largest ``image_rerank`` a node takes (the re-ranking casts every one of these views anew).
MAX_IMAGE_RERANK = 1000


def backend_param(description: str) -> Backend:
    """``backend``: the ray-casting backend, ``auto`` by default."""
    return param("auto", description, choices=BACKEND_NAMES)


def n_rays_param(description: str) -> int:
    """``n_rays``: ray sub-cells per side, 0 to 64 (0, the default: the data set's)."""
    return param(0, description, min_value=0, max_value=64)


def gain_variant_param(description: str) -> str:
    """``gain_variant``: one of :data:`~nbv_prob_cnn.gain.variant.GAIN_VARIANTS`, ``paper`` by default."""
    return param("paper", description, choices=GAIN_VARIANTS)


def surface_blend_param(description: str) -> float:
    """``surface_blend``: the surface methods' blend in [0, 1] (docs/method.md#surface-gain)."""
    return param(DEFAULT_SURFACE_BLEND, description, min_value=0.0, max_value=1.0)


def image_rerank_param(description: str) -> int:
    """``image_rerank``: the surface methods re-rank the view search's best this many views by rays
    through each view's own image, 0 to :data:`MAX_IMAGE_RERANK` (0 or 1: no re-ranking;
    docs/method.md#re-ranking-by-the-image-rays)."""
    return param(DEFAULT_IMAGE_RERANK, description, min_value=0, max_value=MAX_IMAGE_RERANK)
