"""What the opt-in bfloat16 CNN (``cnn_precision``) costs in view ranking and saves in time (issue #35).

On 3DT held-out worlds (seeds 120...), half explored by random views as in ``nbv bench``, the shipped
3DT network's map in float32 (as trained) and in bfloat16 (torch autocast), compared:

* ``max_dp``: the largest probability difference on the unknown cells;
* ``rho_views``: Spearman ρ over every (origin, view) gain of the empty cells of the
  :func:`~studies.cnn_window.workspace` box (the same box as ``nbv study cnn_window``);
* ``same_best``: the planner's best view over the whole grid is float32's;
* ``regret``: ``1 - G(bfloat16's best) / G(float32's best)``, both gains on the float32 map;
* ``cnn_f32_s``, ``cnn_bf16_s``: seconds of each whole-grid completion (after a warm-up).

Run: ``nbv study cnn_precision --out studies/results/cnn_precision``
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.completion.city_scores import spearman
from studies.cnn_window import held_out_state, workspace, write_results


@dataclass
class PrecisionScore:
    """One state's comparison (see the module doc)."""

    seed: int
    max_dp: float
    rho_views: float
    same_best: bool
    regret: float
    cnn_f32_s: float
    cnn_bf16_s: float


def score_precision(state: np.ndarray, seed: int) -> PrecisionScore:
    """float32 against bfloat16 on one state."""
    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.gain import empty_origins, origin_view_gains
    from nbv_prob_cnn.planners import PlanningContext, make_planner

    maps, seconds = {}, {}
    for precision in ("float32", "bfloat16"):
        complete(np.ascontiguousarray(state[:32, :32, :32]), dataset="3dt", precision=precision)  # warm-up
        start = time.perf_counter()
        maps[precision] = complete(state, dataset="3dt", precision=precision)
        seconds[precision] = time.perf_counter() - start
    unknown = state == -1
    max_dp = float(np.abs(maps["bfloat16"] - maps["float32"])[unknown].max()) if unknown.any() else 0.0
    context = PlanningContext.for_dataset("3dt", backend="opencl")
    lo, hi = workspace(state.shape)
    origins = empty_origins(state, region=(tuple(int(v) for v in lo), tuple(int(v) for v in hi)))
    settings = context.gain_settings("prob", "cnn")

    def gains(prob: np.ndarray, cells: np.ndarray) -> np.ndarray:
        return origin_view_gains(state, prob, context.directions, context.active_sensor.r_max, context.membership,
                                 cells, context.backend, settings=settings)  # fmt: skip

    rho = spearman(gains(maps["bfloat16"], origins).ravel(), gains(maps["float32"], origins).ravel())
    best = {}
    for precision in ("float32", "bfloat16"):
        ranked = make_planner("cnn_prob").rank(state, PlanningContext.for_dataset(
            "3dt", backend="opencl", cnn_precision=precision), 1)  # fmt: skip
        best[precision] = ranked[0]
    want, got = best["float32"], best["bfloat16"]
    same = tuple(got.cell) == tuple(want.cell) and got.view_index == want.view_index
    on_exact = float(gains(maps["float32"], np.array([got.cell]))[0, got.view_index])
    return PrecisionScore(seed, max_dp, rho, same, 0.0 if same else 1.0 - on_exact / want.gain,
                          seconds["float32"], seconds["bfloat16"])  # fmt: skip


def summary(scores: list[PrecisionScore]) -> str:
    """Markdown table, one row per state and the means."""
    header = (
        "| seed | max ΔP (unknown cells) | 1 − ρ views | same best view | regret | CNN float32 s | CNN bfloat16 s |"
    )
    lines = [header, "|---|---|---|---|---|---|---|"]
    for s in scores:
        lines.append(f"| {s.seed} | {s.max_dp:.4f} | {1.0 - s.rho_views:.1e} | {'yes' if s.same_best else 'no'} | "
                     f"{s.regret:.4f} | {s.cnn_f32_s:.2f} | {s.cnn_bf16_s:.2f} |")  # fmt: skip
    lines.append(
        f"| all | {max(s.max_dp for s in scores):.4f} | {1.0 - np.mean([s.rho_views for s in scores]):.1e} | "
        f"{sum(s.same_best for s in scores)} / {len(scores)} | {max(s.regret for s in scores):.4f} | "
        f"{np.mean([s.cnn_f32_s for s in scores]):.2f} | {np.mean([s.cnn_bf16_s for s in scores]):.2f} |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[120, 121, 122, 123, 124], help="3DT worlds")
    parser.add_argument("--out", type=Path, default=Path("studies/results/cnn_precision"), help="results folder")
    args = parser.parse_args(argv)
    scores = []
    for seed in args.seeds:
        scores.append(score_precision(held_out_state(seed), seed))
        print(f"seed {seed}: {asdict(scores[-1])}", flush=True)
    table = summary(scores)
    write_results(args.out, scores, f"The 3DT CNN in bfloat16 against float32, 3DT seeds {args.seeds}", "cnn_precision",
                  table)  # fmt: skip
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
