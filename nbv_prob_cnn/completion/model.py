"""The completion encoder-decoder of SPEC §3 (paper §III-A), for 2D and 3D grids.

Architecture of ``CompletionNet(dims, n_conv, first_channels)`` with ``c_i = first_channels * 2**i``:

* input: 2 channels, ``E`` (known empty) and ``O`` (known occupied);
* encoder, conv block ``i = 0 … n_conv-1``: conv k3 s1 p1 ``-> c_i`` + LeakyReLU, conv k3 s2 p1
  ``c_i -> c_i`` + LeakyReLU (halves every spatial size);
* decoder, deconv block ``i = n_conv-1 … 0``: one transposed conv k3 s2 p1 output-padding 1
  ``-> c_i`` + LeakyReLU (doubles every spatial size). The decoder mirrors the encoder: the
  deconv blocks output ``c_{n-1}, …, c_1, c_0`` channels, each half the previous one (as in the
  authors' reference implementation). Its output is concatenated with the *input* of conv block
  ``i`` (the skip connection), so the last deconv output is joined with the 2-channel input;
* a 1×1 conv to 1 channel + sigmoid gives ``P'``; the result is ``P = U·P' + O``.

Example, ``dims=3, n_conv=3, first_channels=16``: encoder ``2→16→16, 16→32→32, 32→64→64``;
decoder ``64→64 (+32 skip) , 96→32 (+16 skip), 48→16 (+2 skip)``; final ``18→1``.

Grids whose sizes are not multiples of ``2**n_conv`` are padded with *unknown* cells at the
high end of each axis and the output is cropped back (:func:`pad_to_multiple` for numpy
grids; :meth:`CompletionNet.forward` does the same on tensors).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional

from nbv_prob_cnn.grid import EMPTY, OCCUPIED, UNKNOWN

#: Negative slope of every LeakyReLU (the paper gives none; 0.3 is the Keras default the
#: original implementation ran with).
LEAKY_SLOPE = 0.3

#: Initial bias of the final 1×1 conv: logit(0.15), so an untrained network outputs P0.
PRIOR_LOGIT = float(np.log(0.15 / 0.85))

#: Default width of the first conv block per dimensionality (SPEC §3).
DEFAULT_FIRST_CHANNELS = {2: 8, 3: 16}


def pad_to_multiple(state: np.ndarray, multiple: int, n_spatial: int | None = None) -> np.ndarray:
    """Pad a ternary grid with ``UNKNOWN`` at the high end of each spatial axis up to a
    multiple of ``multiple``.

    Args:
        state: grid (or a batch of grids) of any integer dtype.
        multiple: every spatial size is rounded up to a multiple of this.
        n_spatial: how many trailing axes are spatial (default: all axes).

    Returns:
        The padded grid (the input itself when no padding is needed). Crop back with
        ``padded[..., :X, :Y(, :Z)]``, i.e. ``padded[tuple(slice(0, s) for s in shape)]``.
    """
    if multiple < 1:
        raise ValueError(f"multiple: expected a positive integer, got {multiple}")
    n_spatial = state.ndim if n_spatial is None else n_spatial
    lead = state.ndim - n_spatial
    pads = [(0, 0)] * lead + [(0, (-size) % multiple) for size in state.shape[lead:]]
    if all(hi == 0 for _, hi in pads):
        return state
    return np.pad(state, pads, mode="constant", constant_values=UNKNOWN)


def encode_state(state: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Ternary grid(s) ``(B, *spatial)`` -> float input ``(B, 2, *spatial)`` with channels E, O."""
    t = torch.as_tensor(state)
    return torch.stack([(t == EMPTY), (t == OCCUPIED)], dim=1).to(torch.float32)


class CompletionNet(nn.Module):
    """Encoder-decoder that completes a partially known grid into a probabilistic map.

    Args:
        dims: 2 (``Conv2d``) or 3 (``Conv3d``).
        n_conv: number of conv blocks (= number of deconv blocks); SPEC §7 per data set.
        first_channels: width of the first conv block (8 in 2D, 16 in 3D by default).
    """

    def __init__(self, dims: int, n_conv: int, first_channels: int | None = None) -> None:
        super().__init__()
        if dims not in (2, 3):
            raise ValueError(f"dims: expected 2 or 3, got {dims}")
        if n_conv < 1:
            raise ValueError(f"n_conv: expected >= 1, got {n_conv}")
        first_channels = DEFAULT_FIRST_CHANNELS[dims] if first_channels is None else first_channels
        if first_channels < 1:
            raise ValueError(f"first_channels: expected >= 1, got {first_channels}")
        self.dims, self.n_conv, self.first_channels = dims, n_conv, first_channels
        conv = nn.Conv2d if dims == 2 else nn.Conv3d
        deconv = nn.ConvTranspose2d if dims == 2 else nn.ConvTranspose3d
        widths = [first_channels * 2**i for i in range(n_conv)]
        skip_channels = [2, *widths[:-1]]  # channels entering each conv block

        self.encoder = nn.ModuleList()
        for c_in, c_out in zip(skip_channels, widths, strict=True):
            self.encoder.append(
                nn.Sequential(
                    conv(c_in, c_out, kernel_size=3, stride=1, padding=1),
                    nn.LeakyReLU(LEAKY_SLOPE),
                    conv(c_out, c_out, kernel_size=3, stride=2, padding=1),
                    nn.LeakyReLU(LEAKY_SLOPE),
                )
            )
        self.decoder = nn.ModuleList()  # decoder[i] mirrors encoder[i]; run from deepest to 0
        c_in = widths[-1]
        for i in reversed(range(n_conv)):
            self.decoder.insert(
                0,
                nn.Sequential(
                    deconv(c_in, widths[i], kernel_size=3, stride=2, padding=1, output_padding=1),
                    nn.LeakyReLU(LEAKY_SLOPE),
                ),
            )
            c_in = widths[i] + skip_channels[i]
        self.final = conv(c_in, 1, kernel_size=1)
        # Start at the prior occupancy (the P0 of Prob. IG) instead of 0.5: with a sigmoid under
        # an MSE loss, the first Adam steps otherwise push the sparse-occupancy 3D grids into a
        # saturated all-empty output whose gradients vanish (seen on 3DU: training stalled at
        # the MSE of predicting 0 everywhere).
        nn.init.constant_(self.final.bias, PRIOR_LOGIT)

    @property
    def multiple(self) -> int:
        """Spatial sizes the layers need (``2**n_conv``); others are padded internally."""
        return 2**self.n_conv

    def config(self) -> dict:
        """Constructor arguments, as stored in a weights file."""
        return {"dims": self.dims, "n_conv": self.n_conv, "first_channels": self.first_channels}

    def forward(self, x: torch.Tensor, return_raw: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Complete a batch.

        Args:
            x: ``(B, 2, *spatial)`` float tensor of E and O (see :func:`encode_state`); any
                spatial size (padded with unknown up to :attr:`multiple`, cropped back).
            return_raw: also return the sigmoid output ``P'``.

        Returns:
            ``P = U·P' + O`` of shape ``(B, 1, *spatial)``; with ``return_raw`` the pair ``(P, P')``.
        """
        if x.ndim != self.dims + 2 or x.shape[1] != 2:
            axes = "X, Y" if self.dims == 2 else "X, Y, Z"
            raise ValueError(f"x: expected shape (B, 2, {axes}), got {tuple(x.shape)}")
        spatial = tuple(x.shape[2:])
        pad = []
        for size in reversed(spatial):  # F.pad lists the last axis first
            pad += [0, (-size) % self.multiple]
        padded = functional.pad(x, pad) if any(pad) else x  # E = O = 0 there: unknown

        skips = []
        h = padded
        for block in self.encoder:
            skips.append(h)
            h = block(h)
        for i in reversed(range(self.n_conv)):
            h = torch.cat([self.decoder[i](h), skips[i]], dim=1)
        raw = torch.sigmoid(self.final(h))
        crop = (slice(None), slice(None), *(slice(0, s) for s in spatial))
        raw = raw[crop]
        empty, occupied = x[:, 0:1], x[:, 1:2]
        prob = (1.0 - empty - occupied) * raw + occupied
        return (prob, raw) if return_raw else prob


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
