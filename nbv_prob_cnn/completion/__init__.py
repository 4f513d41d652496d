"""The completion CNN of docs/method.md#completion-cnn: model, inference, training data and training."""

from nbv_prob_cnn.completion.inference import WeightsError, complete, default_weights_path, load_model
from nbv_prob_cnn.completion.model import CompletionNet, pad_to_multiple
from nbv_prob_cnn.completion.train import train

__all__ = [
    "CompletionNet",
    "WeightsError",
    "complete",
    "default_weights_path",
    "load_model",
    "pad_to_multiple",
    "train",
]
