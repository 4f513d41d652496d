"""One :class:`DatasetSpec` per data set: every fact about ``2d``, ``3du`` and ``3dt`` in one place
(docs/method.md: completion CNN, candidate views, parameters, data sets): grid shape and resolution, sensor,
ray/view parameters, environment
splits and training defaults.

:data:`nbv_prob_cnn.basics.camera.DATASETS` and :data:`nbv_prob_cnn.worlds.DATASETS` are derived from
:data:`DATASET_SPECS` (kept for existing callers).

Environment split (by environment, never by sample; 180 environments per data set):

* train ``0…99`` and validation ``100…119`` (together the 2/3 of docs/method.md#completion-cnn; the epoch kept is the
  one with the lowest validation loss),
* test ``120…179`` (1/3): test MSE, calibration, and the evaluation environments of
docs/method.md#exploration-protocol-and-metrics
  (the first 40 by default). Seeds ``>= 1000`` are reserved for users' own runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from nbv_prob_cnn.basics.sensor import Sensor

#: Number of environments per data set (docs/method.md#data-sets).
N_ENVIRONMENTS = 180
TRAIN_SEEDS: tuple[int, ...] = tuple(range(100))
VALIDATION_SEEDS: tuple[int, ...] = tuple(range(100, 120))
TEST_SEEDS: tuple[int, ...] = tuple(range(120, 180))
#: Seeds from here on are reserved for users' evaluations.
USER_SEED_START = 1000
#: Environments of the full evaluation protocol (docs/method.md#exploration-protocol-and-metrics): the first
#: 40 test environments.
EVALUATION_SEEDS: tuple[int, ...] = TEST_SEEDS[:40]
#: Adam's learning rate of docs/method.md#completion-cnn (``nbv train``'s default on every data set but 3DT).
SPEC_LEARNING_RATE = 1e-3
#: Learning-rate schedules over the epochs of a run (``completion.train.learning_rate``).
LR_SCHEDULES = ("constant", "cosine")


@dataclass(frozen=True)
class TrainingDefaults:
    """Defaults of ``nbv train`` for one data set (sized for the 2-core reference machine)."""

    epochs: int
    crop: int | None  # random training crop edge in cells (None: whole grids)
    batch_size: int
    test_crop: int | None  # fixed validation/test crop edge (None: whole grids)
    lr: float = SPEC_LEARNING_RATE  # Adam's (initial) learning rate
    lr_schedule: str = "constant"  # one of LR_SCHEDULES


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that differs between data sets.

    The first nine fields keep the order of the former ``camera.DatasetDefaults`` (so positional
    construction in tests and scripts keeps working).

    Attributes:
        name: ``2d``, ``3du`` or ``3dt``.
        dims: 2 or 3.
        shape: evaluation grid shape (2D: crops of the ``map_shape`` city maps).
        resolution_m: cell edge in metres.
        sensor: the reference depth sensor (ranges in cells).
        n_rays: ray sub-cells per side (docs/method.md#probabilistic-ray-casting-gain).
        n_conv: conv blocks of the encoder-decoders (docs/method.md#completion-cnn).
        p0: constant occupancy probability of Prob. IG.
        origin_stride: candidate origins every ``origin_stride`` cells per axis (3DT: 2).
        city_n_rays: ray sub-cells per side of D-City-CNN's composite cells (paper: 4).
        city_output_stride: City-CNN outputs one cell every ``city_output_stride`` cells per axis
            (3DT: 8, i.e. three deconv blocks removed, as in the paper).
        map_shape: shape of the generated environments (2D: the 1250×1250 city maps).
        view_range: inclusive range of random views simulated per training environment.
        training: defaults of ``nbv train``.
        train_seeds, validation_seeds, test_seeds: the environment split.
    """

    name: str
    dims: int
    shape: tuple[int, ...]
    resolution_m: float
    sensor: Sensor
    n_rays: int
    n_conv: int
    p0: float = 0.15
    origin_stride: int = 1
    city_n_rays: int = 4
    city_output_stride: int = 1
    map_shape: tuple[int, ...] | None = None
    view_range: tuple[int, int] = (10, 15)
    training: TrainingDefaults = field(default_factory=lambda: TrainingDefaults(15, None, 4, None))
    train_seeds: tuple[int, ...] = TRAIN_SEEDS
    validation_seeds: tuple[int, ...] = VALIDATION_SEEDS
    test_seeds: tuple[int, ...] = TEST_SEEDS

    @property
    def evaluation_seeds(self) -> tuple[int, ...]:
        """The environments of the full evaluation protocol (first 40 of the test split)."""
        return self.test_seeds[:40]


DATASET_SPECS: dict[str, DatasetSpec] = {
    "2d": DatasetSpec(
        "2d", 2, (400, 400), 1.2, Sensor(60.0, None, 128, width_px=520, height_px=1, focal_px=450.0), 16, 6,
        map_shape=(1250, 1250), view_range=(200, 400),
        training=TrainingDefaults(epochs=120, crop=256, batch_size=8, test_crop=400),
    ),
    "3du": DatasetSpec(
        "3du", 3, (64, 64, 64), 0.0116, Sensor(60.0, 46.0, 24, width_px=32, height_px=24, focal_px=28.0), 4, 3,
        view_range=(10, 15), training=TrainingDefaults(epochs=20, crop=None, batch_size=4, test_crop=None),
    ),
    "3dt": DatasetSpec(
        "3dt", 3, (128, 128, 96), 0.0116, Sensor(60.0, 46.0, 128, width_px=128, height_px=96, focal_px=112.0), 4, 4,
        origin_stride=2, city_output_stride=8, view_range=(30, 40),
        # 3DT: at the paper's constant 1e-3 a 20-epoch run became unstable after epoch 5 (docs/cnn_prob_training.md)
        training=TrainingDefaults(epochs=20, crop=64, batch_size=4, test_crop=None, lr=3e-4, lr_schedule="cosine"),
    ),
}  # fmt: skip


def dataset_spec(name: str) -> DatasetSpec:
    """The spec of a data set by name (``2d``, ``3du``, ``3dt``).

    Raises:
        ValueError: unknown name (the message lists the known ones).
    """
    try:
        return DATASET_SPECS[name]
    except KeyError:
        raise ValueError(f"dataset: unknown data set {name!r}; expected one of {sorted(DATASET_SPECS)}") from None


def dataset_for_grid(shape: tuple[int, ...], preferred: str) -> str:
    """The data set whose weights suit a grid of ``shape`` when none is named: the one whose grid
    shape is exactly ``shape``; else ``preferred`` if it has as many dimensions; else the first data
    set (in :data:`DATASET_SPECS` order) with as many dimensions.

    Raises:
        ValueError: no data set has ``len(shape)`` dimensions.
    """
    dims = len(shape)
    for name, spec in DATASET_SPECS.items():
        if tuple(spec.shape) == tuple(shape):
            return name
    if preferred in DATASET_SPECS and DATASET_SPECS[preferred].dims == dims:
        return preferred
    for name, spec in DATASET_SPECS.items():
        if spec.dims == dims:
            return name
    raise ValueError(f"grid: no data set has {dims}D grids (shape {tuple(shape)})")
