"""Running the trained networks: weights files, model cache and :func:`complete`.

A weights file is a ``torch.save`` of ``{"state_dict", "config": {dims, n_conv,
first_channels, dataset, [model, out_channels, head, removed_deconv, extra_deconv]}, "card": {...}}``.
Weights are named per model: ``nbv_prob_cnn/weights/<dataset>_<model>.pt`` where ``<model>`` is
a method's :attr:`~nbv_prob_cnn.planners.registry.MethodSpec.weights` (``cnn_prob`` for the
completion CNN, ``flat_city_cnn``, ``b_city_cnn``, ``d_city_cnn``). Missing or incompatible
weights raise :class:`WeightsError` with the command that retrains them; there is no silent
fallback.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import torch

from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN, check_state
from nbv_prob_cnn.basics.modes import CNN_PRECISIONS
from nbv_prob_cnn.completion.model import CompletionNet, encode_state

_CONFIG_KEYS = ("dims", "n_conv", "first_channels", "dataset")
_ARCHITECTURE_KEYS = ("out_channels", "head", "removed_deconv", "extra_deconv")
#: Model name of the completion CNN (the ``<model>`` of its weights file).
COMPLETION_MODEL = "cnn_prob"
_CACHE: dict[tuple[str, int, str], CompletionNet] = {}
_CACHE_LOCK = threading.Lock()


class WeightsError(ValueError):
    """Completion weights are missing, unreadable or do not fit the request."""


def weights_dir() -> Path:
    """Folder of the weights files: ``$NBV_WEIGHTS_DIR`` when set, else the shipped
    ``nbv_prob_cnn/weights/``."""
    env = os.environ.get("NBV_WEIGHTS_DIR")
    return Path(env).expanduser().resolve() if env else Path(__file__).resolve().parent.parent / "weights"


def default_weights_path(dataset: str, model: str = COMPLETION_MODEL) -> Path:
    """``<weights_dir()>/<dataset>_<model>.pt`` (by default the shipped weights of a model)."""
    if dataset not in DATASETS:
        raise ValueError(f"dataset: unknown data set {dataset!r}; expected one of {sorted(DATASETS)}")
    return weights_dir() / f"{dataset}_{model}.pt"


def retrain_command(dataset: str | None, path: str | Path | None = None, model: str | None = None) -> str:
    """The command that (re)creates a weights file."""
    model = model or COMPLETION_MODEL
    name = dataset if dataset in DATASETS else "{2d,3du,3dt}"
    cmd = f"nbv train --dataset {name}"
    if model != COMPLETION_MODEL:
        cmd += f" --method {model}"
    if path is not None and dataset in DATASETS and Path(path).resolve() != default_weights_path(dataset, model):
        cmd += f" --out {path}"
    return cmd


def _names_from_path(path: Path) -> tuple[str | None, str | None]:
    """``(dataset, model)`` guessed from a file name ``<dataset>_<model>.pt``."""
    dataset, _, model = path.stem.partition("_")
    return (dataset, model or None) if dataset in DATASETS else (None, None)


def cpu_has_bfloat16() -> bool:
    """Whether torch has bfloat16 convolutions on this CPU (oneDNN on AVX512 or AMX)."""
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def check_precision(precision: str, device: torch.device) -> str:
    """``precision`` when it is one of :data:`~nbv_prob_cnn.basics.modes.CNN_PRECISIONS` that ``device`` runs.

    Raises:
        ValueError: an unknown precision, or ``bfloat16`` where torch has no bfloat16 convolutions
            (a CPU without AVX512 or AMX).
    """
    if precision not in CNN_PRECISIONS:
        raise ValueError(f"precision: expected one of {CNN_PRECISIONS}, got {precision!r}")
    if precision == "bfloat16" and device.type == "cpu" and not cpu_has_bfloat16():
        raise ValueError("precision: this CPU has no bfloat16 convolutions (AVX512 or AMX); use 'float32'")
    return precision


def resolve_device(device: str | torch.device | None = None) -> torch.device:
    """``device`` as given, else CUDA when available, else CPU."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def save_weights(
    model: CompletionNet, path: str | Path, dataset: str, card: dict | None = None, name: str = COMPLETION_MODEL
) -> Path:
    """Write a weights file (atomically) and return its path; ``name`` is the model name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "config": {**model.config(), "dataset": dataset, "model": name},
        "card": dict(card or {}),
    }
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)
    return path


def read_weights(path: str | Path, dataset: str | None = None, model: str | None = None) -> dict:
    """Read and validate a weights file (without building the model).

    Raises:
        WeightsError: missing/unreadable file, missing keys, or another data set than
            ``dataset`` or another model than ``model``.
    """
    path = Path(path)
    path_dataset, path_model = _names_from_path(path)
    hint_dataset, hint_model = dataset or path_dataset, model or path_model
    hint = f"train them with `{retrain_command(hint_dataset, path, hint_model)}`"
    what = f"{hint_model or COMPLETION_MODEL} weights"
    if not path.is_file():
        raise WeightsError(f"{path}: {what} not found; {hint}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure means an unusable file
        raise WeightsError(f"{path}: unreadable completion CNN weights ({exc}); {hint}") from exc
    if not isinstance(payload, dict) or "state_dict" not in payload or "config" not in payload:
        raise WeightsError(f"{path}: not a completion CNN weights file (needs state_dict and config); {hint}")
    config = payload["config"]
    missing = [k for k in _CONFIG_KEYS if k not in config]
    if missing:
        raise WeightsError(f"{path}: weights config lacks {missing}; {hint}")
    if dataset is not None and config["dataset"] != dataset:
        raise WeightsError(f"{path}: weights were trained on data set {config['dataset']!r}, not {dataset!r}; {hint}")
    if model is not None and config.get("model", COMPLETION_MODEL) != model:
        raise WeightsError(f"{path}: weights of model {config.get('model')!r}, not {model!r}; {hint}")
    return payload


def build_model(payload: dict, path: str | Path = "<weights>") -> CompletionNet:
    """A :class:`CompletionNet` with the weights of a payload from :func:`read_weights`."""
    config = payload["config"]
    hint = f"train them with `{retrain_command(config.get('dataset'), path, config.get('model'))}`"
    try:
        architecture = {k: config[k] for k in _ARCHITECTURE_KEYS if k in config}
        model = CompletionNet(int(config["dims"]), int(config["n_conv"]), int(config["first_channels"]), **architecture)
        model.load_state_dict(payload["state_dict"], strict=True)
    except (RuntimeError, ValueError, TypeError, KeyError) as exc:
        raise WeightsError(f"{path}: weights do not fit the completion CNN ({exc}); {hint}") from exc
    model.dataset = str(config["dataset"])
    model.model_name = str(config.get("model", COMPLETION_MODEL))
    model.card = dict(payload.get("card", {}))
    return model.eval()


def load_model(
    path: str | Path | None = None,
    dataset: str | None = None,
    device: str | torch.device | None = None,
    model_name: str = COMPLETION_MODEL,
) -> CompletionNet:
    """Load (and cache per file version and device) a completion CNN in eval mode.

    Args:
        path: weights file (default: the shipped weights of ``dataset``).
        dataset: expected data set; checked against the file's config when given.
        device: default CUDA when available, else CPU.

    Raises:
        WeightsError: missing or incompatible weights (the message names the file and the
            ``nbv train`` command that recreates it).
    """
    if path is None:
        if dataset is None:
            raise ValueError("path: give a weights file or a dataset to use its shipped weights")
        path = default_weights_path(dataset, model_name)
    path = Path(path).expanduser().resolve()
    dev = resolve_device(device)
    mtime = path.stat().st_mtime_ns if path.is_file() else -1
    key = (str(path), mtime, str(dev))
    with _CACHE_LOCK:
        model = _CACHE.get(key)
    if model is None:
        model = build_model(read_weights(path, dataset, model_name), path).to(dev)
        with _CACHE_LOCK:
            _CACHE[key] = model
    elif dataset is not None and getattr(model, "dataset", dataset) != dataset:
        raise WeightsError(f"{path}: weights were trained on data set {model.dataset!r}, not {dataset!r}")
    return model


def clear_model_cache() -> None:
    """Forget every cached model (e.g. after retraining in-process)."""
    with _CACHE_LOCK:
        _CACHE.clear()


def _validate(state: np.ndarray, batch: bool) -> np.ndarray:
    if not batch:
        return check_state(state, "state")[None]
    if not isinstance(state, np.ndarray) or state.ndim not in (3, 4) or state.shape[0] == 0:
        shape = getattr(state, "shape", None)
        raise ValueError(f"state: expected a batch (B, X, Y) or (B, X, Y, Z) of ternary grids, got shape {shape}")
    check_state(state.reshape(state.shape[0], -1)[:, :, None], "state")  # dtype and values of the whole batch
    return np.ascontiguousarray(state, dtype=np.int8)


def complete(
    state: np.ndarray,
    model: CompletionNet | str | Path | None = None,
    dataset: str | None = None,
    device: str | torch.device | None = None,
    batch: bool = False,
    chunk: int = 8,
    precision: str = "float32",
) -> np.ndarray:
    """Probabilistic map ``P`` of a ternary grid (docs/method.md#completion-cnn): 0 on known empty, 1 on known
    occupied, the CNN's occupancy probability on unknown cells.

    Args:
        state: ``int8`` grid of -1/0/1 (``(B, …)`` when ``batch``).
        model: a :class:`CompletionNet`, a weights path, or None for the shipped weights of
            ``dataset`` (which defaults to ``2d`` for 2D grids; 3D grids need ``3du``/``3dt``).
        dataset: data set of the shipped weights, also checked against a loaded file.
        device: default CUDA when available, else CPU.
        batch: ``state`` is a batch of grids.
        chunk: grids per forward pass in batch mode.
        precision: one of :data:`~nbv_prob_cnn.basics.modes.CNN_PRECISIONS` (``bfloat16``: the forward pass
            under torch's autocast).

    Returns:
        ``float32`` array of the shape of ``state``.

    Raises:
        ValueError: invalid ``state`` or ``precision``; :class:`WeightsError` for missing/incompatible weights.
    """
    grids = _validate(state, batch)
    dims = grids.ndim - 1
    dev = resolve_device(device)
    if not isinstance(model, CompletionNet):
        if model is None and dataset is None:
            if dims != 2:
                raise ValueError("dataset: required for 3D grids without a model ('3du' or '3dt')")
            dataset = "2d"
        model = load_model(model, dataset, dev)
    elif next(model.parameters()).device != dev:
        model = model.to(dev)
    if model.dims != dims:
        raise ValueError(f"state: a {dims}D grid does not fit a {model.dims}D completion model")
    if model.head != "completion":
        raise ValueError(f"model: a {getattr(model, 'model_name', model.head)} network is not a completion CNN")

    check_precision(precision, dev)
    out = np.empty(grids.shape, dtype=np.float32)
    was_training = model.training
    model.eval()
    try:
        lowered = precision == "bfloat16"
        with torch.inference_mode(), torch.autocast(dev.type, dtype=torch.bfloat16, enabled=lowered):
            for start in range(0, grids.shape[0], max(1, chunk)):
                part = grids[start : start + chunk]
                prob = model(encode_state(part, channels_last=dev.type == "cpu").to(dev))[:, 0]
                out[start : start + chunk] = prob.float().cpu().numpy()
    finally:
        model.train(was_training)
    # Known cells exactly 0 / 1 whatever the arithmetic did.
    out = np.where(grids == UNKNOWN, np.clip(out, 0.0, 1.0), (grids == OCCUPIED).astype(np.float32))
    out = out.astype(np.float32, copy=False)
    return out if batch else out[0]
