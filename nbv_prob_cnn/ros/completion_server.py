"""Node ``completion_server``: the completion CNN as a service (``/nbv/complete``).

Loads the weights of the configured data set at start-up (or on the first request naming
another data set) and keeps them; ``warm_up`` runs one inference on an all-unknown grid of the
data set's shape at start-up, so the first request does not pay torch's first-call set-up.
Missing or incompatible weights are reported in every response (with the command that trains
them); the node keeps serving. ``time_total_s`` of a response is the request's time in this node
(message conversions + inference), ``inference_time_s`` the CNN alone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from nbv_prob_cnn_msgs.srv import CompleteGrid
from rclpy.node import Node

from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.basics.datasets import dataset_for_grid
from nbv_prob_cnn.basics.modes import CNN_PRECISIONS
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import msg_to_grid, probability_to_msg
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.runtime import run_node


@dataclass
class CompletionConfig:
    """Parameters of ``completion_server``."""

    dataset: str = param("3dt", "default weights", choices=tuple(sorted(DATASETS)))
    weights_file: str = param("", "weights file (empty = shipped weights of dataset)")
    device: str = param("auto", "torch device: auto (CUDA if present), cpu, cuda, cuda:N")
    warm_up: bool = param(True, "run one inference at start-up (the first request is then as fast as the next)")
    torch_threads: int = param(
        0, "CPU inference threads; 0 = torch's default (one per core)",
        min_value=0, max_value=1024,
    )  # fmt: skip
    precision: str = param(
        "float32", "the network's arithmetic: float32 (as trained) or bfloat16 (faster on CPUs with AVX512-BF16 "
        "or AMX, probabilities within 0.01)", choices=CNN_PRECISIONS,
    )  # fmt: skip


def torch_threads_text() -> str:
    import torch

    return f"{torch.get_num_threads()} torch thread(s)"


class CompletionServer(Node):
    """Serves ``CompleteGrid``: ternary grid in, probability grid out."""

    def __init__(self) -> None:
        super().__init__("completion_server")
        self.config = cfg = declare_config(self, CompletionConfig, mirror=False)
        from nbv_prob_cnn.completion.inference import WeightsError, check_precision, load_model, resolve_device

        self._device = resolve_device(None if cfg.device == "auto" else cfg.device)
        check_precision(cfg.precision, self._device)  # refused at start: bfloat16 where torch has none
        if self._device.type == "cpu" and cfg.torch_threads > 0:
            # one thread per core by default: in the main job on 2 cores (camera, TF and joint-state
            # streams beside it) 1 thread gave a median CNN stage of 1.82 s against 1.21-1.44 s
            import torch

            torch.set_num_threads(cfg.torch_threads)
        self._load_model, self._weights_error = load_model, WeightsError
        # offered before the model loads: a client that finds it waits for the answer (served once
        # the node spins) instead of giving up on a service that is not there yet
        self.create_service(CompleteGrid, names.COMPLETE, self._complete)
        try:  # load now so the first request is fast; failures are reported per request
            model = self._model_for(cfg.dataset)
            warm = ""
            if cfg.warm_up:
                from nbv_prob_cnn.completion import complete

                start = time.perf_counter()
                complete(np.full(DATASETS[cfg.dataset].shape, -1, dtype=np.int8), model=model, device=self._device,
                         precision=cfg.precision)  # fmt: skip
                warm = f", warmed up in {time.perf_counter() - start:.2f} s"
            on = f"{self._device}" + (f" ({torch_threads_text()})" if self._device.type == "cpu" else "")
            on += f", {cfg.precision}"
            self.get_logger().info(f"completion_server ready: {cfg.dataset} weights on {on}{warm}")
        except WeightsError as exc:
            self.get_logger().error(str(exc))

    def _model_for(self, dataset: str):
        cfg = self.config
        path = cfg.weights_file if (cfg.weights_file and dataset == cfg.dataset) else None
        return self._load_model(path, dataset, self._device)

    def _complete(self, request: CompleteGrid.Request, response: CompleteGrid.Response):
        from nbv_prob_cnn.completion.tiled import complete_region

        received = time.perf_counter()
        try:
            state, geometry = msg_to_grid(request.grid)
            dataset = request.dataset or dataset_for_grid(state.shape, self.config.dataset)
            if dataset not in DATASETS:
                raise ValueError(f"dataset: unknown data set {dataset!r}; expected one of {sorted(DATASETS)}")
            if DATASETS[dataset].dims != geometry.dims:
                raise ValueError(f"a {geometry.dims}D grid cannot use the {dataset} ({DATASETS[dataset].dims}D) model")
            model = self._model_for(dataset)
            start = time.perf_counter()
            # by tiles of at most MAX_WINDOW_CELLS (16 M) cells with the receptive field as halo: a room
            # (up to MAX_GRID_CELLS, 67 M) in bounded memory; one pass, as before, up to that size
            prob = complete_region(state, None, model=model, device=self._device, precision=self.config.precision)
            response.inference_time_s = time.perf_counter() - start
            response.probability = probability_to_msg(
                prob, geometry, request.grid.header.frame_id, request.grid.header.stamp
            )
            response.success = True
            self.get_logger().info(
                f"complete: {dataset} {'x'.join(map(str, state.shape))} in {time.perf_counter() - received:.2f} s "
                f"(inference {response.inference_time_s:.2f} s)"
            )
        except ValueError as exc:  # WeightsError is a ValueError
            response.success = False
            response.message = str(exc)
            self.get_logger().warning(f"complete: {exc}")
        response.time_total_s = time.perf_counter() - received
        return response


def main(args: list[str] | None = None) -> int:
    return run_node(CompletionServer, args)


if __name__ == "__main__":
    raise SystemExit(main())
