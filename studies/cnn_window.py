"""What completing only a window around the workspace costs in view ranking (issue #35).

With ``PlanningContext.cnn_window`` the completion CNN sees only the workspace's box grown by a
margin and the unknown cells outside take Prob. IG's constant ``p0``
(:func:`~nbv_prob_cnn.completion.tiled.complete_window`). On 3DT held-out worlds (seeds 120...),
half explored by random views as in ``nbv bench``, with a workspace box of :data:`WORKSPACE_CELLS`
cells centred on the table (z from the table top up), this compares, for every empty cell of the box
as an origin, the view gains on the window's map with those on the whole-grid CNN map:

* ``rho_views``: Spearman ρ over every (origin, view) gain;
* ``rho_origins``: ρ over each origin's best gain;
* ``same_best``: the window's best view is the whole map's;
* ``regret``: ``1 - G(window's best) / G(best)``, both gains on the whole map (0 when the same view wins);
* ``cnn_s``: seconds of the window's completion (the whole grid's: ``margin`` -1).

Run: ``nbv study cnn_window --out studies/results/cnn_window``
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from nbv_prob_cnn.completion.city_scores import spearman

#: Width (cells) of the workspace box: 0.37 m at 3DT's 1.16 cm.
WORKSPACE_CELLS = 32
#: Margins (cells) of the windows compared.
MARGINS = (0, 16, 32, 48)


@dataclass
class WindowScore:
    """One (state, margin) comparison (see the module doc)."""

    seed: int
    margin: int
    window_cells: int
    origins: int
    rho_views: float
    rho_origins: float
    same_best: bool
    regret: float
    cnn_s: float


def workspace(shape: tuple[int, ...], width: int = WORKSPACE_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """Cells ``[lo, hi)`` of a box ``width`` wide, centred in x and y, from the table top (z 8) up."""
    lo = np.array([shape[0] // 2 - width // 2, shape[1] // 2 - width // 2, 8])
    return lo, np.minimum(lo + width, shape)


def held_out_state(seed: int) -> np.ndarray:
    """World ``seed`` of 3DT, half explored by random views (``nbv bench``'s protocol)."""
    from nbv_prob_cnn.bench.planning import half_explored
    from nbv_prob_cnn.planners import PlanningContext
    from nbv_prob_cnn.worlds import load_or_generate

    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(seed), backend="opencl")
    return half_explored(load_or_generate("3dt", seed), context)


def score_windows(state: np.ndarray, seed: int, margins=MARGINS, width: int = WORKSPACE_CELLS) -> list[WindowScore]:
    """The scores of every margin on one state."""
    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.completion.tiled import complete_window
    from nbv_prob_cnn.gain import empty_origins, origin_view_gains
    from nbv_prob_cnn.planners import PlanningContext
    from nbv_prob_cnn.planners.candidates import grown_box

    context = PlanningContext.for_dataset("3dt", backend="opencl")
    lo, hi = workspace(state.shape, width)
    origins = empty_origins(state)
    origins = origins[np.all((origins >= lo) & (origins < hi), axis=1)]
    if origins.shape[0] < 2:
        raise ValueError(f"seed {seed}: fewer than 2 empty cells in the workspace")
    settings = context.gain_settings("prob", "cnn")

    def gains(prob: np.ndarray) -> np.ndarray:
        return origin_view_gains(state, prob, context.directions, context.active_sensor.r_max, context.membership,
                                 origins, context.backend, settings=settings)  # fmt: skip

    start = time.perf_counter()
    whole_prob = complete(state, dataset="3dt")
    cnn_s = time.perf_counter() - start
    whole = gains(whole_prob)
    scores = [WindowScore(seed, -1, state.size, origins.shape[0], 1.0, 1.0, True, 0.0, cnn_s)]
    best = int(np.argmax(whole))
    for margin in margins:
        box = grown_box(np.array([lo, hi - 1]), (margin,) * 3, state.shape)
        assert box is not None
        start = time.perf_counter()
        prob = complete_window(state, box, context.defaults.p0, dataset="3dt")
        cnn_s = time.perf_counter() - start
        local = gains(prob)
        chosen = int(np.argmax(local))
        cells = int(np.prod([b - a for a, b in zip(*box, strict=True)]))
        scores.append(WindowScore(
            seed, margin, cells, origins.shape[0], spearman(local.ravel(), whole.ravel()),
            spearman(local.max(axis=1), whole.max(axis=1)), chosen == best,
            float(1.0 - whole.flat[chosen] / whole.flat[best]), cnn_s,
        ))  # fmt: skip
    return scores


def summary(scores: list[WindowScore]) -> str:
    """Markdown table: per margin the mean ρ, the share of same best views, the mean and largest regret."""
    lines = ["| margin (cells) | window cells | ρ views | ρ origins | same best view | regret mean / max | CNN s |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for margin in sorted({s.margin for s in scores}):
        rows = [s for s in scores if s.margin == margin]
        name = "whole grid" if margin < 0 else str(margin)
        lines.append(
            f"| {name} | {np.mean([r.window_cells for r in rows]):,.0f} | {np.mean([r.rho_views for r in rows]):.3f} | "
            f"{np.mean([r.rho_origins for r in rows]):.3f} | {sum(r.same_best for r in rows)} / {len(rows)} | "
            f"{np.mean([r.regret for r in rows]):.3f} / {max(r.regret for r in rows):.3f} | "
            f"{np.mean([r.cnn_s for r in rows]):.2f} |"
        )
    return "\n".join(lines)


def write_results(out: Path, scores: list, title: str, study: str, table: str) -> None:
    """``scores.csv`` (one row per score, a dataclass) and ``summary.md`` (``title``, the command of
    ``nbv study <study>``, the ``table``) in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "scores.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[f.name for f in fields(scores[0])])
        writer.writeheader()
        writer.writerows(asdict(s) for s in scores)
    (out / "summary.md").write_text(f"# {title}\n\nCommand: `nbv study {study} --out {out}`\n\n{table}\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[120, 121, 122, 123, 124], help="3DT worlds")
    parser.add_argument("--margins", type=int, nargs="+", default=list(MARGINS), help="window margins (cells)")
    parser.add_argument("--out", type=Path, default=Path("studies/results/cnn_window"), help="folder of the results")
    args = parser.parse_args(argv)
    if any(m < 0 for m in args.margins):
        raise ValueError(f"--margins: expected margins >= 0 cells, got {args.margins}")
    scores = []
    for seed in args.seeds:
        scores += score_windows(held_out_state(seed), seed, args.margins)
        print(f"seed {seed}: done", flush=True)
    table = summary(scores)
    title = f"CNN window around a {WORKSPACE_CELLS}-cell workspace, 3DT seeds {args.seeds}"
    write_results(args.out, scores, title, "cnn_window", table)
    print(table)
    return 0
