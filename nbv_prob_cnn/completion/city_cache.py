"""Cached City-CNN training sets (docs/training.md): every example's input channels and omniscient ray
gains computed once, so that a training step only reads files and never ray-casts.

What is cached, per data set and environment (one *chunk*, one compressed ``.npz`` per seed):

* **Entries**: training environments get one entry per augmentation rotation
  (:func:`~nbv_prob_cnn.completion.data.rotations`) and per stored crop; validation/test
  environments get one unrotated entry on the fixed crop of
  :func:`~nbv_prob_cnn.completion.train.fixed_examples` (seeded ``[seed, 404]``), so cached
  validation/test examples are the on-the-fly ones.
* **Region of an entry**: a box of the rotated grid on the output lattice. 3D data sets store
  the whole rotated grid (3DU trains on whole grids; 3DT's random 64³ training crops are cut
  from it at read time with the same random boxes as on the fly, its lattice being one cell in
  512). 2D stores :data:`CROPS_PER_ROTATION` random training crops per rotation (a whole
  1250² map would hold ~0.5 M origins × 72 rays per rotation); an epoch draws one of them per
  item, so 2D crops come from a fixed pool instead of fresh positions each epoch.
* **Per region**: ``E`` and ``F`` (of the whole rotated grid, then cropped; ``uint8``) and, per
  ray set the three variants use (``N_rays`` of Flat/B-City-CNN and D-City-CNN's
  ``city_n_rays``; one set in 3D, where both are 4), the omniscient gains ``(N, R)`` of the
  region's empty lattice cells in ``np.argwhere`` order, stored as the kernel's ``float32``
  (float16 would halve the files, but it moved B-City-CNN's best view between near-tied views:
  target vectors differed by up to 1.46 on 3DU seed 0), so a cached example equals the one
  computed on the fly.

An example of any variant is then assembled from the region
(:func:`~nbv_prob_cnn.planners.city_cnn.assemble_city_target` and
:func:`~nbv_prob_cnn.planners.city_cnn.lattice_output_mask`), the same functions the on-the-fly
path (:meth:`~nbv_prob_cnn.completion.tasks.TrainingTask.example`) ends in.

Files: ``<NBV_CACHE_DIR or ~/.cache/nbv_prob_cnn>/city_examples/<dataset>/v<DATA_VERSION>.<CITY_CACHE_VERSION>/
<layout>/{train,eval}_<seed>.npz``, where ``<layout>`` names the crops (e.g. ``crop256x2_eval400``).
Each chunk is written to a temporary file and renamed, so an interrupted generation leaves
whole chunks only and resumes by skipping them (:func:`ensure_chunks`). A chunk that cannot be
read raises :class:`CityCacheError` naming the file (delete it to regenerate it).
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.datasets import DatasetSpec, dataset_spec
from nbv_prob_cnn.basics.grid import frontier_mask, lattice_index
from nbv_prob_cnn.completion.data import DATA_VERSION, cache_root, crop_box, load_or_generate_sample, rotations
from nbv_prob_cnn.completion.tasks import Example

#: Version of the chunk format and content (part of the cache path).
CITY_CACHE_VERSION = 2
#: Stored training crops per rotation where training crops a grid larger than the crop (2D).
CROPS_PER_ROTATION = 2

ROLES = ("train", "eval")


class CityCacheError(ValueError):
    """A chunk is missing, unreadable or of another layout/version."""


@dataclass(frozen=True)
class CacheLayout:
    """Which regions a data set's chunks hold.

    Attributes:
        dataset: data set name.
        region: edge of the stored training regions (None: the whole rotated grid).
        crops_per_rotation: stored training regions per rotation (1 for whole grids).
        eval_crop: the fixed validation/test crop edge (None: whole grids).
    """

    dataset: str
    region: int | None
    crops_per_rotation: int
    eval_crop: int | None

    @classmethod
    def for_training(cls, dataset: str, crop: int | None, eval_crop: int | None) -> CacheLayout:
        """The layout of a run with training crop ``crop``: 3D grids are stored whole (crops are
        cut at read time), 2D maps as :data:`CROPS_PER_ROTATION` crops of edge ``crop``."""
        spec = dataset_spec(dataset)
        if spec.dims == 3:
            return cls(dataset, None, 1, eval_crop)
        if crop is None:
            raise ValueError(
                "crop: cached 2D City-CNN training needs a training crop (a whole 1250² map holds "
                "~0.5 M origins × 72 rays per rotation, ~600 MB a chunk): pass --crop"
            )
        return cls(dataset, int(crop), CROPS_PER_ROTATION, eval_crop)

    @property
    def name(self) -> str:
        region = "whole" if self.region is None else f"crop{self.region}x{self.crops_per_rotation}"
        return f"{region}_eval{'whole' if self.eval_crop is None else self.eval_crop}"

    @property
    def spec(self) -> DatasetSpec:
        return dataset_spec(self.dataset)

    def directory(self) -> Path:
        return cache_root() / "city_examples" / self.dataset / f"v{DATA_VERSION}.{CITY_CACHE_VERSION}" / self.name

    def chunk_path(self, seed: int, role: str) -> Path:
        if role not in ROLES:
            raise ValueError(f"role: expected one of {ROLES}, got {role!r}")
        return self.directory() / f"{role}_{int(seed)}.npz"

    def entries_per_train_chunk(self) -> int:
        return len(rotations(self.dataset)) * self.crops_per_rotation


def ray_sets(spec: DatasetSpec) -> dict[int, str]:
    """``{N_rays: a variant using it}``: the ray sets whose gains a chunk stores."""
    sets: dict[int, str] = {}
    for method in ("flat_city_cnn", "d_city_cnn"):  # b_city_cnn uses flat_city_cnn's rays
        from nbv_prob_cnn.planners.city_cnn import CityGeometry

        sets.setdefault(CityGeometry.of(method, spec).n_rays, method)
    return sets


@dataclass(frozen=True)
class Region:
    """One stored region: ``E``/``F`` of a box of a rotated grid and the omniscient ray gains
    of its empty lattice cells (``gains[n_rays]``: ``(N, R)``, ``np.argwhere`` order)."""

    seed: int
    rotation: int
    start: tuple[int, ...]
    empty: np.ndarray  # bool (*region)
    frontier: np.ndarray  # bool (*region)
    gains: dict[int, np.ndarray]

    def example(self, method: str, spec: DatasetSpec, sub_box: tuple[slice, ...] | None = None) -> Example:
        """The example of ``method`` on the region, or on ``sub_box`` (relative to the region,
        starts on the output lattice)."""
        from nbv_prob_cnn.planners.city_cnn import CityGeometry, assemble_city_target, lattice_output_mask

        geometry = CityGeometry.of(method, spec)
        s = geometry.stride
        sub_box = sub_box or tuple(slice(0, n) for n in self.empty.shape)
        if any(b.start % s for b in sub_box):
            raise ValueError(f"sub_box: starts {[b.start for b in sub_box]} are not on the {s}-cell lattice")
        every = lattice_index(len(sub_box), s)
        empty_lattice = self.empty[every]
        index = np.full(empty_lattice.shape, -1, dtype=np.int64)
        index[empty_lattice] = np.arange(int(empty_lattice.sum()))
        lattice_box = tuple(slice(b.start // s, -(-b.stop // s)) for b in sub_box)
        sub_index = index[lattice_box]
        kept = sub_index >= 0
        local = np.argwhere(kept)
        gains = self.gains[geometry.n_rays]
        if gains.shape[0] != index.max() + 1:
            raise CityCacheError(f"region of seed {self.seed}: {gains.shape[0]} gains for {index.max() + 1} origins")
        picked = gains[sub_index[kept]].astype(np.float32) if local.size else None
        target = assemble_city_target(method, spec, picked, local, sub_index.shape)
        inputs = np.stack([self.empty[sub_box], self.frontier[sub_box]]).astype(np.float32)
        mask = lattice_output_mask(geometry, kept)[None]
        return Example(inputs, target, mask)


def compute_region(
    spec: DatasetSpec,
    seed: int,
    rotation: int,
    state: np.ndarray,
    truth: np.ndarray,
    box: tuple[slice, ...],
    backend: str = "auto",
) -> Region:
    """Ray-cast one region of a (rotated) grid: its ``E``/``F`` and the omniscient gains of every
    ray set (:func:`ray_sets`) from its empty lattice cells, rays cast through the whole grid."""
    from nbv_prob_cnn.planners.city_cnn import CityGeometry, lattice_origins_in_box, omniscient_ray_gains

    gains = {}
    for n_rays, method in ray_sets(spec).items():
        geometry = CityGeometry.of(method, spec)
        origins, _, _ = lattice_origins_in_box(geometry, state, box)
        if origins.size:
            gains[n_rays] = omniscient_ray_gains(state, truth, geometry, origins, backend).astype(np.float32)
        else:
            gains[n_rays] = np.zeros((0, geometry.directions.shape[0]), dtype=np.float32)
    empty = state == 0
    frontier = frontier_mask(state)
    return Region(int(seed), int(rotation), tuple(b.start for b in box), empty[box], frontier[box], gains)


def region_boxes(layout: CacheLayout, seed: int, role: str, shape: tuple[int, ...]) -> list[tuple[int, tuple]]:
    """``[(rotation index, box)]`` of the entries of a chunk (``shape``: the unrotated grid)."""
    align = layout.spec.city_output_stride
    if role == "eval":
        return [(0, crop_box(shape, layout.eval_crop, np.random.default_rng([int(seed), 404]), align))]
    out = []
    for k, rot in enumerate(rotations(layout.dataset)):
        rotated_shape = rot.apply(np.empty(shape, dtype=np.bool_)).shape
        for j in range(layout.crops_per_rotation):
            rng = np.random.default_rng([int(seed), k, j, 0xC17E])
            out.append((k, crop_box(rotated_shape, layout.region, rng, align)))
    return out


def generate_chunk(layout: CacheLayout, seed: int, role: str, backend: str = "auto") -> Path:
    """Simulate (or read) the environment's training sample, ray-cast its regions and write the
    chunk atomically; returns its path."""
    sample = load_or_generate_sample(layout.dataset, seed)
    rots = rotations(layout.dataset)
    arrays: dict[str, np.ndarray] = {}
    entries = []
    for i, (k, box) in enumerate(region_boxes(layout, seed, role, sample.state.shape)):
        state, truth = rots[k].apply(sample.state), rots[k].apply(sample.truth)
        region = compute_region(layout.spec, seed, k, state, truth, box, backend)
        arrays[f"e{i}_empty"] = region.empty.astype(np.uint8)
        arrays[f"e{i}_frontier"] = region.frontier.astype(np.uint8)
        for n_rays, gains in region.gains.items():
            arrays[f"e{i}_gains{n_rays}"] = gains
        entries.append(
            {
                "rotation": k,
                "start": [int(b.start) for b in box],
                "shape": list(region.empty.shape),
                "n_origins": {str(n): int(g.shape[0]) for n, g in region.gains.items()},
            }
        )
    meta = {
        "dataset": layout.dataset,
        "seed": int(seed),
        "role": role,
        "layout": layout.name,
        "data_version": DATA_VERSION,
        "cache_version": CITY_CACHE_VERSION,
        "generator_version": sample.generator_version,
        "entries": entries,
    }
    path = layout.chunk_path(seed, role)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
    os.replace(tmp, path)
    return path


def ensure_chunks(
    layout: CacheLayout,
    seeds_by_role: Mapping[str, Sequence[int]],
    backend: str = "auto",
    progress: bool = True,
    on_chunk: Callable[[Path], None] | None = None,
    share: tuple[int, int] = (0, 1),
) -> tuple[int, int]:
    """Generate the missing chunks (existing ones are skipped, not read); returns
    ``(generated, skipped)``. Shows a tqdm bar over the chunks to generate. ``share=(r, n)``:
    only every ``n``-th missing chunk from the ``r``-th (data-parallel workers split the work)."""
    from tqdm import tqdm

    todo = [(s, r) for r, seeds in seeds_by_role.items() for s in seeds if not layout.chunk_path(s, r).is_file()]
    todo = todo[share[0] :: share[1]]
    total = sum(len(seeds) for seeds in seeds_by_role.values())
    with tqdm(total=len(todo), desc=f"city examples {layout.dataset}", unit="env", disable=not progress) as bar:
        for seed, role in todo:
            path = generate_chunk(layout, seed, role, backend)
            if on_chunk:
                on_chunk(path)
            bar.update(1)
    return len(todo), total - len(todo)


class ChunkReader:
    """Reads regions from the chunks of one layout (each ``read`` opens the file and
    decompresses only the arrays of that entry)."""

    def __init__(self, layout: CacheLayout) -> None:
        self.layout = layout
        self._meta: dict[tuple[int, str], dict] = {}

    def _open(self, seed: int, role: str) -> tuple[Path, dict]:
        path = self.layout.chunk_path(seed, role)
        if (seed, role) in self._meta:
            return path, self._meta[(seed, role)]
        if not path.is_file():
            raise CityCacheError(
                f"{path}: missing City-CNN example chunk of {self.layout.dataset} seed {seed} ({role}); "
                "generate it with ensure_chunks / `nbv train --method <city method>` (it fills the cache first)"
            )
        try:
            with np.load(path) as data:
                meta = json.loads(bytes(data["meta"]).decode())
        except (OSError, KeyError, ValueError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
            raise CityCacheError(f"{path}: unreadable City-CNN example chunk ({exc}); delete it to regenerate") from exc
        expected = (self.layout.dataset, int(seed), role, self.layout.name, DATA_VERSION, CITY_CACHE_VERSION)
        found = tuple(meta.get(k) for k in ("dataset", "seed", "role", "layout", "data_version", "cache_version"))
        if found != expected:
            raise CityCacheError(f"{path}: chunk of {found}, expected {expected}; delete it to regenerate")
        self._meta[(seed, role)] = meta
        return path, meta

    def n_entries(self, seed: int, role: str) -> int:
        return len(self._open(seed, role)[1]["entries"])

    def entry_shape(self, seed: int, role: str, entry: int) -> tuple[int, ...]:
        """Shape of an entry's region (from the chunk's header)."""
        path, meta = self._open(seed, role)
        if not 0 <= entry < len(meta["entries"]):
            raise CityCacheError(f"{path}: no entry {entry} (it holds {len(meta['entries'])})")
        return tuple(int(n) for n in meta["entries"][entry]["shape"])

    def generator_version(self, seed: int, role: str) -> int:
        return int(self._open(seed, role)[1]["generator_version"])

    def read(self, seed: int, role: str, entry: int) -> Region:
        """Entry ``entry`` of the chunk of ``seed``.

        Raises:
            CityCacheError: missing or unreadable chunk, or an entry it does not hold.
        """
        path, meta = self._open(seed, role)
        if not 0 <= entry < len(meta["entries"]):
            raise CityCacheError(f"{path}: no entry {entry} (it holds {len(meta['entries'])})")
        info = meta["entries"][entry]
        try:
            with np.load(path) as data:
                empty = data[f"e{entry}_empty"].astype(bool)
                frontier = data[f"e{entry}_frontier"].astype(bool)
                gains = {int(n): data[f"e{entry}_gains{n}"] for n in info["n_origins"]}
        except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise CityCacheError(f"{path}: unreadable entry {entry} ({exc}); delete the file to regenerate") from exc
        for n, g in gains.items():
            if g.shape[0] != info["n_origins"][str(n)]:
                raise CityCacheError(f"{path}: entry {entry} holds {g.shape[0]} gains, its header says "
                                     f"{info['n_origins'][str(n)]}; delete the file to regenerate")  # fmt: skip
        return Region(int(seed), int(info["rotation"]), tuple(info["start"]), empty, frontier, gains)


def cache_size_bytes(layout: CacheLayout) -> tuple[int, int]:
    """``(bytes, chunks)`` of the layout's directory on disk."""
    files = list(layout.directory().glob("*.npz"))
    return sum(f.stat().st_size for f in files), len(files)


class LazyExamples(Sequence[Example]):
    """A sequence whose items are built when read (City-CNN examples can be large: a 3DU
    D-City-CNN target is 256³ float32, 67 MB)."""

    def __init__(self, build: Callable[[int], Example], n: int) -> None:
        self._build = build
        self._n = int(n)

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return [self._build(i) for i in range(*index.indices(self._n))]
        if not -self._n <= index < self._n:
            raise IndexError(index)
        return self._build(index % self._n)


class CachedCityExamples:
    """The examples of one City-CNN training run, read from the chunks of ``layout``."""

    def __init__(
        self,
        method: str,
        layout: CacheLayout,
        train_seeds: Sequence[int],
        validation_seeds: Sequence[int],
        test_seeds: Sequence[int],
        crop: int | None,
    ) -> None:
        self.method = method
        self.layout = layout
        self.spec = layout.spec
        self.reader = ChunkReader(layout)
        self.train_seeds = list(train_seeds)
        self.validation_seeds = list(validation_seeds)
        self.test_seeds = list(test_seeds)
        self.crop = crop

    def train_example(self, index: int, rotation: int, rng: np.random.Generator, build: bool = True) -> Example | None:
        """Training environment ``index`` under rotation ``rotation``: one of the stored crops
        (2D, drawn from ``rng``) or a random crop of the stored whole grid (3D, the box
        :func:`~nbv_prob_cnn.completion.data.crop_box` draws from ``rng``, as on the fly).
        ``build`` False: None, after the same draws (data-parallel workers skip others' items)."""
        k = self.layout.crops_per_rotation
        j = int(rng.integers(k)) if k > 1 else 0
        seed, entry = self.train_seeds[index], rotation * k + j
        sub_box = self._sub_box(self.reader.entry_shape(seed, "train", entry), rng)
        if not build:
            return None
        return self.reader.read(seed, "train", entry).example(self.method, self.spec, sub_box)

    def _sub_box(self, shape: tuple[int, ...], rng: np.random.Generator) -> tuple[slice, ...] | None:
        if self.layout.region is not None:
            return None  # a stored crop is the training crop
        return crop_box(shape, self.crop, rng, self.spec.city_output_stride)

    def first_examples(self, n: int, rng: np.random.Generator) -> list[Example]:
        """Unrotated examples of the first ``n`` training environments (the gain head's start)."""
        out = []
        for seed in self.train_seeds[:n]:
            region = self.reader.read(seed, "train", 0)
            out.append(region.example(self.method, self.spec, self._sub_box(region.empty.shape, rng)))
        return out

    def unrotated_training(self) -> LazyExamples:
        """The first stored (unrotated) example of every training environment, uncropped."""
        return LazyExamples(
            lambda i: self.reader.read(self.train_seeds[i], "train", 0).example(self.method, self.spec),
            len(self.train_seeds),
        )

    def fixed(self, seeds: Sequence[int]) -> LazyExamples:
        """The validation/test examples of ``seeds`` (their eval chunks)."""
        seeds = list(seeds)
        return LazyExamples(lambda i: self.reader.read(seeds[i], "eval", 0).example(self.method, self.spec), len(seeds))

    def generator_versions(self) -> list[int]:
        versions = {self.reader.generator_version(s, "train") for s in self.train_seeds}
        versions |= {self.reader.generator_version(s, "eval") for s in self.validation_seeds + self.test_seeds}
        return sorted(versions)
