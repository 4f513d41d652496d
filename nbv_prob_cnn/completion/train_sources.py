"""Where a training run's examples come from: the simulated samples, turned into examples on the fly
(:class:`SampleSource`), or the cached City-CNN training set (:class:`CachedSource`). Both give the shuffled
training items, the fixed validation and test items, and the examples of the mean-target baseline."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from nbv_prob_cnn.completion.city_cache import CachedCityExamples
from nbv_prob_cnn.completion.data import TrainingSample, crop_box, rotations
from nbv_prob_cnn.completion.tasks import Example, TrainingTask


def fixed_examples(task: TrainingTask, samples: Sequence[TrainingSample], crop: int | None) -> list[Example]:
    """Validation/test items: unrotated, one fixed crop per environment (seeded by the environment)."""
    examples = []
    for sample in samples:
        box = crop_box(sample.state.shape, crop, np.random.default_rng([sample.seed, 404]), task.align)
        examples.append(task.example(sample.state, sample.truth, box))
    return examples


class SampleSource:
    """Examples computed from the simulated samples on the fly (``cnn_prob``; City-CNNs with
    ``cache=False``: their targets are ray-cast in every step)."""

    def __init__(
        self,
        task: TrainingTask,
        train_samples: list[TrainingSample],
        val_samples: list[TrainingSample],
        test_samples: list[TrainingSample],
        crop: int | None,
        crop_edge: int | None,
    ) -> None:
        self.task, self.crop, self.crop_edge = task, crop, crop_edge
        self.train_samples, self.val_samples, self.test_samples = train_samples, val_samples, test_samples
        self.rots = rotations(task.spec.name)

    def train_example(self, index: int, rotation: int, rng: np.random.Generator, build: bool = True) -> Example | None:
        """The item's example (its random crop drawn from ``rng``); None, with the same draw,
        when ``build`` is False."""
        sample, rot = self.train_samples[index], self.rots[rotation]
        box = crop_box(rot.rotated_shape(sample.state.shape), self.crop, rng, self.task.align)
        if not build:
            return None
        return self.task.example(rot.apply(sample.state), rot.apply(sample.truth), box)

    def first_examples(self, n: int, rng: np.random.Generator) -> list[Example]:
        first = self.train_samples[:n]
        boxes = [crop_box(s.state.shape, self.crop, rng, self.task.align) for s in first]
        return [self.task.example(s.state, s.truth, b) for s, b in zip(first, boxes, strict=True)]

    def mean_target_examples(self) -> list[Example]:
        """The mean-target baseline's examples: the fixed crops of the first 8 training grids."""
        return fixed_examples(self.task, self.train_samples[:8], self.crop)

    def validation(self) -> list[Example]:
        return fixed_examples(self.task, self.val_samples, self.crop_edge)

    def test(self) -> list[Example]:
        return fixed_examples(self.task, self.test_samples, self.crop_edge)

    def generator_versions(self) -> list[int]:
        return sorted({s.generator_version for s in self.train_samples + self.val_samples + self.test_samples})


class CachedSource:
    """City-CNN examples read from the cached training set (no ray casting)."""

    def __init__(self, examples: CachedCityExamples) -> None:
        self.examples = examples

    def train_example(self, index: int, rotation: int, rng: np.random.Generator, build: bool = True) -> Example | None:
        return self.examples.train_example(index, rotation, rng, build)

    def first_examples(self, n: int, rng: np.random.Generator) -> list[Example]:
        return self.examples.first_examples(n, rng)

    def mean_target_examples(self) -> Sequence[Example]:
        """The mean-target baseline's examples: the unrotated stored example of every training grid."""
        return self.examples.unrotated_training()

    def validation(self) -> Sequence[Example]:
        return self.examples.fixed(self.examples.validation_seeds)

    def test(self) -> Sequence[Example]:
        return self.examples.fixed(self.examples.test_seeds)

    def generator_versions(self) -> list[int]:
        return self.examples.generator_versions()
