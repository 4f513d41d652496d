"""The pose-scoring settings ``nbv gain-study`` compares: rays (the view search's ``N_rays`` set, or
rays across the pose's own image), sensor model, gain sampling and the planning range. Each variant
changes the scoring service's defaults (``/nbv/evaluate_views``) in the settings it names."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

from nbv_prob_cnn.gain.sampling import check_sampling, check_sensor_model


@dataclass(frozen=True)
class ScoringVariant:
    """One pose-scoring set-up.

    Attributes:
        n_rays: sub-cells per side of the view search's ray set (``gain_server``'s ``n_rays``; 0 = the
            data set's); read only when ``rays_across`` is 0.
        sensor: gain sensor model, ``paper`` or ``returns`` (``sensor_model``).
        sampling: ``rounded`` or ``exact`` ray sampling.
        rays_across: 0: the view search's rays inside the pose's frustum; ``n``: ``n`` rays across
            the pose's own image (:func:`~nbv_prob_cnn.gain.frustum_rays.frustum_rays`).
        max_range_m: planning range (``max_range_m``; 0 = the data set's, in cells).
    """

    n_rays: int = 0
    sensor: str = "paper"
    sampling: str = "rounded"
    rays_across: int = 0
    max_range_m: float = 0.0

    def __post_init__(self) -> None:
        check_sensor_model(self.sensor)
        check_sampling(self.sampling)
        if self.n_rays < 0 or self.n_rays == 1:
            raise ValueError(f"n_rays: expected 0 (the data set's) or at least 2, got {self.n_rays}")
        if self.rays_across < 0:
            raise ValueError(f"rays_across: expected 0 (the view search's rays) or a positive count, got "
                             f"{self.rays_across}")  # fmt: skip
        if not self.max_range_m >= 0:
            raise ValueError(f"max_range_m: expected 0 (the data set's) or a range in metres, got {self.max_range_m}")

    @property
    def label(self) -> str:
        """A short name: ``rays`` (``n_rays=N`` or ``across=N``), then sensor and sampling, then the range."""
        rays = f"across={self.rays_across}" if self.rays_across else f"n_rays={self.n_rays}"
        text = f"{rays} {self.sensor} {self.sampling}"
        return text + (f" range={self.max_range_m:g}m" if self.max_range_m else "")


#: The keys of ``--vary KEY=V1,V2,...`` and how each value is read.
VARY_KEYS: dict[str, type] = {"n_rays": int, "sensor": str, "sampling": str, "rays_across": int, "max_range_m": float}


def parse_vary(spec: str) -> tuple[str, list]:
    """``KEY=V1,V2,...`` as ``(key, values)``.

    Raises:
        ValueError: no ``=``, an unknown key, an empty or unreadable value (the message names them).
    """
    key, sep, values = spec.partition("=")
    key = key.strip()
    if not sep or key not in VARY_KEYS:
        raise ValueError(f"--vary: expected KEY=V1,V2,... with KEY one of {sorted(VARY_KEYS)}, got {spec!r}")
    items = [v.strip() for v in values.split(",")]
    if not all(items):
        raise ValueError(f"--vary {key}: empty value in {spec!r}")
    try:
        return key, [VARY_KEYS[key](v) for v in items]
    except ValueError:
        raise ValueError(f"--vary {key}: cannot read {values!r} as {VARY_KEYS[key].__name__} values") from None


def cross_variants(base: ScoringVariant, specs: Sequence[str]) -> list[ScoringVariant]:
    """Every combination of the ``--vary`` values, each applied to ``base`` (the service's defaults);
    ``base`` alone without specs. Duplicates are dropped (``n_rays`` is not read with ``rays_across``), order
    kept; ``base`` always comes first.

    Raises:
        ValueError: a bad spec, a key given twice, a value the variant refuses, or several ``n_rays`` where
            no variant reads them (every ``rays_across`` non-zero).
    """
    parsed = [parse_vary(s) for s in specs]
    keys = [k for k, _ in parsed]
    if len(set(keys)) != len(keys):
        raise ValueError(f"--vary: a key given twice in {list(specs)}")
    values = dict(parsed)
    across = values.get("rays_across", [base.rays_across])
    if len(set(values.get("n_rays", []))) > 1 and all(across):
        raise ValueError(
            f"--vary n_rays: not read while rays are cast across each pose's image (rays_across "
            f"{', '.join(map(str, across))}{'' if 'rays_across' in values else ', the default'}): add rays_across=0 "
            f"(the view search's rays), e.g. --vary rays_across=0,{across[0]}"
        )
    found = [base]
    for combination in itertools.product(*[values for _, values in parsed]):
        variant = replace(base, **dict(zip(keys, combination, strict=True)))
        if variant.rays_across:  # the view search's rays are not read: one variant whatever n_rays
            variant = replace(variant, n_rays=base.n_rays)
        if variant not in found:
            found.append(variant)
    return found
