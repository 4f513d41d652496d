"""``nbv world``: generate one environment (docs/method.md#data-sets) and write it with a preview picture."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "world"
HELP = "Generate one world (2d, 3du or 3dt) from a seed and write it as .npz plus a preview PNG."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.worlds import DATASETS

    parser.add_argument("--dataset", choices=DATASETS, required=True, help="data set of the world")
    parser.add_argument("--seed", type=int, required=True, help="generator seed (>= 0)")
    parser.add_argument("--out", required=True, help="world file to write (.npz)")
    parser.add_argument("--png", help="preview picture to write (default: --out with suffix .png)")


def run(args: argparse.Namespace) -> int:
    import time

    from nbv_prob_cnn.worlds import generate_world
    from nbv_prob_cnn.worlds.preview import save_preview

    out = Path(args.out)
    if out.suffix != ".npz":
        out = out.with_name(out.name + ".npz")  # numpy would append it anyway
    png = Path(args.png) if args.png else out.with_suffix(".png")
    start = time.perf_counter()
    world = generate_world(args.dataset, args.seed)
    elapsed = time.perf_counter() - start
    out.parent.mkdir(parents=True, exist_ok=True)
    world.save(out)
    save_preview(world, png)
    grid = world.ground_truth
    print(f"world {world.dataset} seed {world.seed} (generator v{world.generator_version}), {elapsed:.2f} s")
    print(f"  shape      {' x '.join(map(str, grid.shape))} cells of {world.resolution:g} m")
    print(f"  occupied   {grid.mean():.2%} ({int(grid.sum())} cells)")
    print(f"  objects    {len(world.meshes)}")
    if world.table:
        print(f"  table top  {world.table['height_m']:.4f} m, thickness {world.table['thickness_m']:.4f} m")
    print(f"wrote {out}")
    print(f"wrote {png}")
    return 0
