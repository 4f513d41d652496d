"""The CNN suite of ``nbv bench`` (``--suite cnn``): CNN inference and a whole planning iteration per
method at ~50 % explored, planning time per view along an exploration, and the CNN's inference path
against its layers as trained; every time measured side by side in one run."""

from __future__ import annotations

import time

import numpy as np

from nbv_prob_cnn.bench.planning import _defaults, _fresh_grid, _time, half_explored
from nbv_prob_cnn.bench.table_lines import Echo, EchoedLines
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.sensing.observe import observe

#: Methods timed along an exploration: the paper's and the surface gain, on the same grids.
EXPLORATION_METHODS = ("cnn_prob", "cnn_surface")


def cnn_table(seed: int = 1000, repeats: int = 3, echo: Echo | None = None) -> str:
    """CNN inference time and a full ``cnn_prob`` planning iteration (CNN + ray casting + views)
    per data set at ~50 % explored, next to ``prob_ig`` and ``cnn_surface`` (the surface gain on the same
    map, with its re-ranking of the best views by their image rays and without it; times over
    ``cnn_prob``'s, measured side by side); markdown table (``echo``: each line as soon as it is measured)."""
    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.worlds import load_or_generate

    lines = EchoedLines([
        ("| data set | grid | CNN inference (s) | cnn_prob iteration (s) | prob_ig iteration (s) "
        "| cnn_surface iteration (s) | cnn_surface / cnn_prob | without re-ranking (s) | ratio |"),
        "|---|---|---|---|---|---|---|---|---|",
    ], echo)  # fmt: skip
    for dataset in ("2d", "3du", "3dt"):
        world = load_or_generate(dataset, seed)
        rng = np.random.default_rng(seed)
        context = PlanningContext(_defaults(dataset), rng=rng, backend="opencl")
        unranked = PlanningContext(_defaults(dataset), rng=rng, backend="opencl", image_rerank=0)
        state = half_explored(world, context)
        complete(state, dataset=dataset)  # warm-up: load the weights
        t_cnn = _time(lambda: complete(state, dataset=dataset), repeats)  # noqa: B023 - used right here
        cnn, constant, surface = make_planner("cnn_prob"), make_planner("prob_ig"), make_planner("cnn_surface")
        t_plan = _time(lambda: cnn.plan(state, context), repeats)  # noqa: B023
        t_constant = _time(lambda: constant.plan(state, context), repeats)  # noqa: B023
        t_surface = _time(lambda: surface.plan(state, context), repeats)  # noqa: B023
        t_unranked = _time(lambda: surface.plan(state, unranked), repeats)  # noqa: B023
        shape = "×".join(map(str, world.shape))
        lines.append(f"| {dataset.upper()} | {shape} | {t_cnn:.3f} | {t_plan:.3f} | {t_constant:.3f} "
                     f"| {t_surface:.3f} | {t_surface / t_plan:.2f} "
                     f"| {t_unranked:.3f} | {t_unranked / t_plan:.2f} |")  # fmt: skip
    return "\n".join(lines)


def cnn_layout_table(seed: int = 1000, repeats: int = 3, echo: Echo | None = None) -> str:
    """Forward time of every shipped 3D network with the layers as trained (autograd on, frozen
    weights) against the inference path (channels-last deconvs, see ``CompletionNet._upsample``),
    side by side on the same half-explored grid; largest output difference; markdown table (``echo``:
    each line as soon as it is measured)."""
    import copy

    import torch

    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.inference import load_model, resolve_device
    from nbv_prob_cnn.completion.tasks import TrainingTask
    from nbv_prob_cnn.worlds import load_or_generate

    device = resolve_device(None)
    lines = EchoedLines([
        f"CNN forward, {torch.get_num_threads()} torch threads on {device}:",
        "",
        "| data set | network | output | as trained (s) | inference path (s) | ratio | max difference |",
        "|---|---|---|---|---|---|---|",
    ], echo)  # fmt: skip
    for dataset in ("3du", "3dt"):
        world = load_or_generate(dataset, seed)
        context = PlanningContext(_defaults(dataset), rng=np.random.default_rng(seed), backend="opencl")
        state = half_explored(world, context)
        for method in ("cnn_prob", "flat_city_cnn", "b_city_cnn", "d_city_cnn"):
            model = copy.deepcopy(load_model(None, dataset, device, model_name=method))
            model.requires_grad_(False)
            x = TrainingTask(method, dataset_spec(dataset)).encode(state[None]).to(device)

            def plain(model=model, x=x):
                with torch.enable_grad():  # the layers as in training; nothing to differentiate
                    return model(x)

            def inference(model=model, x=x):
                with torch.inference_mode():
                    return model(x)

            difference = float((plain() - inference()).abs().max())  # also the warm-up
            t_plain, t_inference = _time(plain, repeats), _time(inference, repeats)
            out = "×".join(map(str, model.output_shape(state.shape)))
            lines.append(
                f"| {dataset.upper()} | {method} | {model.out_channels}×{out} | {t_plain:.3f} | {t_inference:.3f} | "
                f"{t_plain / t_inference:.2f} | {difference:.1e} |"
            )
    return "\n".join(lines)


def exploration_plan_table(
    seed: int = 1000, repeats: int = 3, views: int = 20, echo: Echo | None = None, progress: bool = True
) -> str:
    """Planning time per view along an exploration, per data set: ``cnn_surface`` explores the world of
    ``seed`` from a random first view for ``views`` views; on the grid before each view every method of
    :data:`EXPLORATION_METHODS` plans (best of ``repeats`` wall-clock times, each marching its grid anew;
    the CPU seconds of that run beside). Sums over the views, mean per view and the ratios to ``cnn_prob``;
    markdown table (``echo``: each line as soon as it is measured; ``progress``: a bar per data set)."""
    from tqdm import tqdm

    from nbv_prob_cnn.exploration.explore import first_view
    from nbv_prob_cnn.worlds import load_or_generate

    lines = EchoedLines([
        ("| data set | views | cnn_prob per view (s) | cnn_surface per view (s) | ratio "
         "| cnn_prob CPU per view (s) | cnn_surface CPU per view (s) | CPU ratio |"),
        "|---|---|---|---|---|---|---|---|",
    ], echo)  # fmt: skip
    for dataset in ("2d", "3du", "3dt"):
        world = load_or_generate(dataset, seed)
        context = PlanningContext(_defaults(dataset), rng=np.random.default_rng(seed), backend="opencl")
        planners = {name: make_planner(name) for name in EXPLORATION_METHODS}
        state = np.full(world.shape, -1, dtype=np.int8)
        choice = first_view(world, context)
        wall = dict.fromkeys(EXPLORATION_METHODS, 0.0)
        cpu = dict.fromkeys(EXPLORATION_METHODS, 0.0)
        done = 0
        for _ in tqdm(range(views), desc=f"{dataset} exploration", unit="view", disable=not progress):
            observe(state, world.ground_truth, choice.cell, context.orientations[choice.view_index],
                    context.active_sensor)  # fmt: skip
            found = {}
            for name, planner in planners.items():
                if done == 0:
                    planner.plan(state, context)  # warm-up: kernel builds, weights
                best = (float("inf"), 0.0)
                for _ in range(max(1, repeats)):
                    _fresh_grid()
                    start, cpu_start = time.perf_counter(), time.process_time()
                    found[name] = planner.plan(state, context)
                    best = min(best, (time.perf_counter() - start, time.process_time() - cpu_start))
                wall[name] += best[0]
                cpu[name] += best[1]
            done += 1
            following = found["cnn_surface"]
            if following is None:
                break
            choice = following
        p, s = "cnn_prob", "cnn_surface"
        lines.append(
            f"| {dataset.upper()} | {done} | {wall[p] / done:.3f} | {wall[s] / done:.3f} | {wall[s] / wall[p]:.2f} "
            f"| {cpu[p] / done:.3f} | {cpu[s] / done:.3f} | {cpu[s] / cpu[p]:.2f} |"
        )
    return "\n".join(lines)
