"""The completion encoder-decoder of docs/method.md#completion-cnn (paper §III-A), for 2D and 3D grids.

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

The same encoder-decoder serves the City-CNN baselines (docs/method.md#methods, paper §III-D/§IV) through
three options, with the completion network as the default:

* ``out_channels`` and ``head``: ``"completion"`` (1 channel, ``P = U·P' + O``), ``"sigmoid"``
  (gains in [0, 1]) or ``"tanh"`` (B-City-CNN's vectors in [−1, 1]);
* ``removed_deconv``: the last (shallowest) deconv blocks dropped, so the output has one cell
  per ``2**removed_deconv`` cells per axis (3DT City-CNNs: 3, i.e. an 8× stride);
* ``extra_deconv``: deconv blocks added after the last one (no skip), each doubling the output
  resolution (D-City-CNN: ``log2(N_rays)`` for its composite cells).

On a CPU the forward pass runs in the channels-last layout (``channels_last`` /
``channels_last_3d``): oneDNN's convolutions are faster on it. Measured with 2 torch threads on a
2-core AMD EPYC: the 3DT completion forward pass 0.82 -> 0.52 s, the 2D one on a 1248² map 0.77
-> 0.44 s, a training step of the 3DU Flat City-CNN 3.33 -> 3.04 s; outputs equal to 1e-6.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN

#: Negative slope of every LeakyReLU (the paper gives none; 0.3 is the Keras default the
#: original implementation ran with).
LEAKY_SLOPE = 0.3
#: The channels-last memory format of a 2D / 3D network's activations (used on a CPU).
CHANNELS_LAST = {2: torch.channels_last, 3: torch.channels_last_3d}

#: Initial bias of the final 1×1 conv: logit(0.15), so an untrained network outputs P0.
PRIOR_LOGIT = float(np.log(0.15 / 0.85))
#: Initial bias of the final 1×1 conv of the City-CNN gain heads (``"sigmoid"``): logit(0.1),
#: about the mean gain target on empty cells (measured on 2D crops: 0.10–0.16 by variant).
GAIN_PRIOR_LOGIT = float(np.log(0.1 / 0.9))

#: Default width of the first conv block per dimensionality (docs/method.md#completion-cnn).
DEFAULT_FIRST_CHANNELS = {2: 8, 3: 16}

#: Output heads of :class:`CompletionNet`.
HEADS = ("completion", "sigmoid", "tanh")


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


def encode_state(state: np.ndarray | torch.Tensor, channels_last: bool = False) -> torch.Tensor:
    """Ternary grid(s) ``(B, *spatial)`` -> float input ``(B, 2, *spatial)`` with channels E, O;
    ``channels_last``: stored channels innermost (the layout of the CPU forward pass, which then
    needs no copy of it)."""
    t = torch.as_tensor(state)
    if channels_last:
        return torch.stack([(t == EMPTY), (t == OCCUPIED)], dim=-1).to(torch.float32).movedim(-1, 1)
    return torch.stack([(t == EMPTY), (t == OCCUPIED)], dim=1).to(torch.float32)


class CompletionNet(nn.Module):
    """Encoder-decoder that completes a partially known grid into a probabilistic map.

    Args:
        dims: 2 (``Conv2d``) or 3 (``Conv3d``).
        n_conv: number of conv blocks (= number of deconv blocks); per data set
            (docs/method.md#parameters-per-data-set).
        first_channels: width of the first conv block (8 in 2D, 16 in 3D by default).
    """

    #: Set by :func:`~nbv_prob_cnn.completion.inference.load_model`: the data set, the model
    #: name (``cnn_prob`` or a City-CNN) and the model card of the loaded weights.
    dataset: str
    model_name: str
    card: dict

    def __init__(
        self,
        dims: int,
        n_conv: int,
        first_channels: int | None = None,
        out_channels: int = 1,
        head: str = "completion",
        removed_deconv: int = 0,
        extra_deconv: int = 0,
    ) -> None:
        super().__init__()
        if head not in HEADS:
            raise ValueError(f"head: expected one of {HEADS}, got {head!r}")
        if head == "completion" and out_channels != 1:
            raise ValueError("out_channels: the completion head has exactly 1 output channel")
        if not 0 <= removed_deconv < n_conv or extra_deconv < 0 or out_channels < 1:
            raise ValueError(
                f"removed_deconv must be in [0, n_conv), extra_deconv >= 0, out_channels >= 1; got "
                f"{removed_deconv}, {extra_deconv}, {out_channels}"
            )
        if dims not in (2, 3):
            raise ValueError(f"dims: expected 2 or 3, got {dims}")
        if n_conv < 1:
            raise ValueError(f"n_conv: expected >= 1, got {n_conv}")
        first_channels = DEFAULT_FIRST_CHANNELS[dims] if first_channels is None else first_channels
        if first_channels < 1:
            raise ValueError(f"first_channels: expected >= 1, got {first_channels}")
        self.dims, self.n_conv, self.first_channels = dims, n_conv, first_channels
        self.out_channels, self.head = out_channels, head
        self.removed_deconv, self.extra_deconv = removed_deconv, extra_deconv
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
        self.decoder = nn.ModuleList()  # decoder[j] mirrors encoder[removed + j]; run from deepest
        c_in = widths[-1]
        for i in reversed(range(removed_deconv, n_conv)):
            self.decoder.insert(
                0,
                nn.Sequential(
                    deconv(c_in, widths[i], kernel_size=3, stride=2, padding=1, output_padding=1),
                    nn.LeakyReLU(LEAKY_SLOPE),
                ),
            )
            c_in = widths[i] + skip_channels[i]
        self.extra = nn.ModuleList()
        for _ in range(extra_deconv):
            self.extra.append(
                nn.Sequential(
                    deconv(c_in, first_channels, kernel_size=3, stride=2, padding=1, output_padding=1),
                    nn.LeakyReLU(LEAKY_SLOPE),
                )
            )
            c_in = first_channels
        self.final = conv(c_in, out_channels, kernel_size=1)
        # Start at the prior occupancy (the P0 of Prob. IG) instead of 0.5: with a sigmoid under
        # an MSE loss, the first Adam steps otherwise push the sparse-occupancy 3D grids into a
        # saturated all-empty output whose gradients vanish (seen on 3DU: training stalled at
        # the MSE of predicting 0 everywhere).
        # The City-CNN gain heads start near their mean target for the same reason.
        if head != "tanh" and self.final.bias is not None:
            nn.init.constant_(self.final.bias, PRIOR_LOGIT if head == "completion" else GAIN_PRIOR_LOGIT)

    @property
    def multiple(self) -> int:
        """Spatial sizes the layers need (``2**n_conv``); others are padded internally."""
        return 2**self.n_conv

    @property
    def output_scale(self) -> float:
        """Output cells per input cell along each axis (``2**(extra - removed)``)."""
        return 2.0 ** (self.extra_deconv - self.removed_deconv)

    def config(self) -> dict:
        """Constructor arguments, as stored in a weights file."""
        return {
            "dims": self.dims,
            "n_conv": self.n_conv,
            "first_channels": self.first_channels,
            "out_channels": self.out_channels,
            "head": self.head,
            "removed_deconv": self.removed_deconv,
            "extra_deconv": self.extra_deconv,
        }

    def output_shape(self, spatial: tuple[int, ...]) -> tuple[int, ...]:
        """Spatial output shape for an input of shape ``spatial`` (strided outputs round up)."""
        up, down = 2**self.extra_deconv, 2**self.removed_deconv
        return tuple(-(-size * up // down) for size in spatial)

    def forward(self, x: torch.Tensor, return_raw: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Complete a batch.

        Args:
            x: ``(B, 2, *spatial)`` float tensor of E and O (see :func:`encode_state`; City-CNN
                heads: E and F); any spatial size (padded with zeros up to :attr:`multiple`,
                cropped back).
            return_raw: also return the sigmoid output ``P'`` (completion head only).

        Returns:
            completion head: ``P = U·P' + O`` of shape ``(B, 1, *spatial)``; with ``return_raw``
            the pair ``(P, P')``. Other heads: ``(B, out_channels, *output_shape(spatial))``.
        """
        if x.ndim != self.dims + 2 or x.shape[1] != 2:
            axes = "X, Y" if self.dims == 2 else "X, Y, Z"
            raise ValueError(f"x: expected shape (B, 2, {axes}), got {tuple(x.shape)}")
        spatial = tuple(x.shape[2:])
        pad = []
        for size in reversed(spatial):  # F.pad lists the last axis first
            pad += [0, (-size) % self.multiple]
        padded = functional.pad(x, pad) if any(pad) else x  # E = O = 0 there: unknown
        if padded.device.type == "cpu":  # oneDNN's convolutions are faster channels-last (module doc)
            padded = padded.contiguous(memory_format=CHANNELS_LAST[self.dims])

        skips = []
        h = padded
        for block in self.encoder:
            skips.append(h)
            h = self._encode(block, h)
        parts: list[torch.Tensor] = []
        for j in reversed(range(len(self.decoder))):
            parts = [self._upsample(self.decoder[j], h), skips[self.removed_deconv + j]]
            h = torch.cat(parts, dim=1) if j or self.extra else h  # the last pair reaches the 1x1 conv unjoined
        for block in self.extra:
            h = self._upsample(block, h)
            parts = [h]
        del h
        skips.clear()
        out = self._final(parts)
        raw = torch.tanh(out) if self.head == "tanh" else torch.sigmoid(out)
        crop = (slice(None), slice(None), *(slice(0, s) for s in self.output_shape(spatial)))
        raw = raw[crop]
        if self.head != "completion":
            return raw
        empty, occupied = x[:, 0:1], x[:, 1:2]
        prob = (1.0 - empty - occupied) * raw + occupied
        return (prob, raw) if return_raw else prob

    def _upsample(self, block: nn.Module, h: torch.Tensor) -> torch.Tensor:
        """A deconv block. Without autograd in 3D it runs in the channels-last layout with an
        in-place activation: the same numbers up to float rounding, 3.5x faster on a CPU for the
        large deconvs of the D-City-CNN (whose last one writes 16 channels at 4x the grid size)."""
        if torch.is_grad_enabled() or self.dims != 3:
            return block(h)
        deconv, _activation = block.children()  # the activation is applied in place below
        h = deconv(h.contiguous(memory_format=torch.channels_last_3d))
        return functional.leaky_relu_(h, LEAKY_SLOPE)

    def _encode(self, block: nn.Module, h: torch.Tensor) -> torch.Tensor:
        """A conv block; without autograd its activations run in place (the same numbers, one
        full-size activation less in memory)."""
        if torch.is_grad_enabled():
            return block(h)
        for layer in block.children():
            h = functional.leaky_relu_(h, LEAKY_SLOPE) if isinstance(layer, nn.LeakyReLU) else layer(h)
        return h

    def _final(self, parts: list[torch.Tensor]) -> torch.Tensor:
        """The 1x1 output conv of ``parts`` joined along the channels. On channels-last inputs
        without autograd, one matrix product per part over its channels, summed: torch's 1x1 conv3d
        takes a slow path on that layout, and joining the last deconv's output with the input would
        copy the largest activation once more (3DT: 194 -> 130 bytes per cell at the peak)."""
        fast = parts[0].ndim == 5 and not torch.is_grad_enabled()
        if not fast or not all(p.is_contiguous(memory_format=torch.channels_last_3d) for p in parts):
            return self.final(parts[0] if len(parts) == 1 else torch.cat(parts, dim=1))
        weight = self.final.weight.reshape(self.out_channels, -1)
        out: torch.Tensor | None = None
        first = 0
        for part in parts:
            last = part.permute(0, 2, 3, 4, 1)  # a contiguous view: channels innermost
            term = last.reshape(-1, last.shape[-1]) @ weight[:, first : first + last.shape[-1]].t()
            out = term if out is None else out.add_(term)
            first += last.shape[-1]
        assert out is not None
        if self.final.bias is not None:
            out += self.final.bias
        return out.reshape(*parts[0].shape[:1], *parts[0].shape[2:], self.out_channels).permute(0, 4, 1, 2, 3)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
