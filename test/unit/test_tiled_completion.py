"""Tiled and region-restricted completion (nbv_prob_cnn/completion/tiled.py): the receptive field
against autograd, tiles against whole-grid inference on a tiny network, and the alignment and halo
that equality needs (the shipped 3DT weights: test_local_planning.py)."""

import numpy as np
import pytest
import torch

from nbv_prob_cnn.basics.region import check_region
from nbv_prob_cnn.completion import complete
from nbv_prob_cnn.completion.model import CompletionNet
from nbv_prob_cnn.completion.tiled import (
    complete_region,
    complete_window,
    halo_cells,
    plan_tiles,
    receptive_interval,
    receptive_radius,
)


def _net(dims: int, n_conv: int, seed: int = 0) -> CompletionNet:
    torch.manual_seed(seed)
    net = CompletionNet(dims, n_conv, first_channels=4).eval()
    with torch.no_grad():  # a non-trivial output everywhere (the default init is near-constant)
        for p in net.parameters():
            p.normal_(0.0, 0.5)
    return net


def _state(rng, shape, p_unknown=0.5):
    return rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[p_unknown, 0.9 - p_unknown, 0.1])


@pytest.mark.parametrize("n_conv", [1, 2, 3, 4, 5])
def test_receptive_radius_is_the_hand_derived_3_times_2_to_the_n_minus_3(n_conv):
    net = CompletionNet(3, n_conv, first_channels=2)
    assert receptive_radius(net) == 3 * 2**n_conv - 3
    assert halo_cells(net) == -(-(3 * 2**n_conv - 3) // 2**n_conv) * 2**n_conv


def test_receptive_interval_is_the_support_of_the_gradient():
    """Independent check: the input cells with a nonzero gradient of one output cell (autograd,
    float64, random weights) are exactly the computed interval, for every phase of the stride."""
    net = _net(2, 2).double()
    size = 48
    x = torch.zeros((1, 2, size, 5), dtype=torch.float64)
    x[0, 0] = torch.rand((size, 5), generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    for position in range(16, 24):
        inp = x.clone().requires_grad_(True)
        _, raw = net(inp, return_raw=True)
        raw[0, 0, position, 2].backward()
        rows = torch.nonzero(inp.grad.abs().sum(dim=(0, 1, 3)) > 0).ravel()
        assert (int(rows.min()), int(rows.max())) == receptive_interval(net, position)


def test_tiles_equal_whole_grid_inference_on_a_tiny_network(rng):
    net = _net(3, 2)
    state = _state(rng, (37, 29, 21))
    whole = complete(state, model=net)
    tiles = plan_tiles(state.shape, check_region(None, state.shape), net.multiple, halo_cells(net), 12_000)
    assert len(tiles) >= 4  # several tiles, cores start on multiples of 4 (the total stride)
    assert all(lo % 4 == 0 for t in tiles for lo in t.window[0])
    tiled = complete_region(state, model=net, max_window_cells=12_000)
    assert np.abs(tiled - whole).max() <= 1e-5
    # a region that starts off the stride: its values are the whole grid's, p0 / known elsewhere
    region = ((5, 3, 2), (30, 17, 21))
    part = complete_region(state, region, model=net, fill=0.25, max_window_cells=8000)
    inside = tuple(slice(a, b) for a, b in zip(*region, strict=True))
    assert np.abs(part[inside] - whole[inside]).max() <= 1e-5
    outside = np.ones(state.shape, dtype=bool)
    outside[inside] = False
    expected = np.where(state == -1, 0.25, (state == 1).astype(np.float32))
    np.testing.assert_array_equal(part[outside], expected[outside])


def test_a_short_halo_or_a_misaligned_window_changes_the_result(rng):
    """What equality needs: a halo below the receptive field, or a window that does not start on
    a multiple of the total stride, gives other numbers than the whole grid."""
    net = _net(3, 2)
    state = _state(rng, (40, 24, 16))
    whole = complete(state, model=net)
    short = complete_region(state, model=net, max_window_cells=5000, halo=4)
    assert np.abs(short - whole).max() > 1e-3
    core = (slice(16, 24), slice(None), slice(None))
    for start in (4, 6):  # 8 cells of context below the core, window start on / off the stride 4
        window = complete(np.ascontiguousarray(state[start:]), model=net)
        shifted = window[16 - start : 24 - start]
        if start % 4 == 0:
            assert np.abs(shifted - whole[core]).max() <= 1e-5
        else:
            assert np.abs(shifted - whole[core]).max() > 1e-3


def test_cores_without_unknown_cells_skip_the_network(rng, monkeypatch):
    import nbv_prob_cnn.completion.tiled as tiled

    net = _net(3, 1)
    state = _state(rng, (16, 16, 8), p_unknown=0.0)
    state[:4, :4, :4] = -1
    calls = []
    monkeypatch.setattr(tiled, "complete", lambda s, **k: calls.append(s.shape) or complete(s, **k))
    out = complete_region(state, model=net, max_window_cells=400)
    tiles = plan_tiles(state.shape, check_region(None, state.shape), net.multiple, halo_cells(net), 400)
    with_unknown = [t for t in tiles if np.any(state[t.slices("core")] == -1)]
    assert 1 <= len(with_unknown) < len(tiles) and len(calls) == len(with_unknown)
    np.testing.assert_array_equal(out[state != -1], (state[state != -1] == 1).astype(np.float32))
    np.testing.assert_allclose(out, complete(state, model=net), atol=1e-5)


def test_window_completion_uses_p0_outside(rng):
    net = _net(3, 2)
    state = _state(rng, (24, 24, 16))
    window = ((4, 8, 0), (20, 24, 16))
    out = complete_window(state, window, 0.15, model=net)
    inside = tuple(slice(a, b) for a, b in zip(*window, strict=True))
    np.testing.assert_allclose(out[inside], complete(np.ascontiguousarray(state[inside]), model=net), atol=1e-6)
    rest = out.copy()
    rest[inside] = -5
    assert set(np.unique(rest[state == -1])) <= {-5, np.float32(0.15)}


def test_bad_regions_are_named(rng):
    net = _net(3, 1)
    state = _state(rng, (8, 8, 8))
    with pytest.raises(ValueError, match="region"):
        complete_region(state, ((0, 0), (4, 4)), model=net)
    with pytest.raises(ValueError, match="region"):
        complete_region(state, ((9, 0, 0), (12, 4, 4)), model=net)
    with pytest.raises(ValueError, match="window"):
        complete_window(state, ((2, 2, 2), (2, 5, 5)), 0.15, model=net)
    with pytest.raises(ValueError, match="halo"):
        complete_region(state, model=net, halo=3)


def test_bfloat16_tiles_equal_its_whole_grid_pass_and_keep_known_cells(rng, bf16):
    """In bfloat16 too the tiles give the one-pass numbers, and known cells stay exactly 0 / 1 (how close
    bfloat16 comes to float32 on the shipped weights: test_local_planning.py)."""
    net = _net(3, 2)
    state = _state(rng, (37, 29, 21))
    lowered = complete(state, model=net, precision="bfloat16")
    tiled = complete_region(state, model=net, max_window_cells=12_000, precision="bfloat16")
    assert np.abs(tiled - lowered).max() <= 1e-5
    known = state != -1
    np.testing.assert_array_equal(lowered[known], (state[known] == 1).astype(np.float32))
    assert lowered.dtype == np.float32 and np.all((lowered >= 0) & (lowered <= 1))
    window = complete_window(state, ((4, 4, 0), (33, 25, 21)), 0.2, model=net, precision="bfloat16")
    np.testing.assert_array_equal(window[known], lowered[known])


def test_an_unknown_precision_is_named(rng):
    state = _state(rng, (8, 8, 8))
    with pytest.raises(ValueError, match="precision"):
        complete(state, model=_net(3, 2), precision="float16")
    with pytest.raises(ValueError, match="precision"):
        complete_region(state, model=_net(3, 2), precision="half")
