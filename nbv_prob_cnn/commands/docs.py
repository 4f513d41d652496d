"""``nbv docs nodes --out docs/nodes.md``: write reference pages generated from the code."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "docs"
HELP = "Write a generated reference page: `nodes` = every node's topics, services, actions and parameters."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("page", choices=["nodes"], help="which page")
    parser.add_argument("--out", type=Path, help="file to write (default: print to stdout)")
    parser.add_argument("--check", action="store_true", help="do not write; exit 1 when --out differs from the code")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.ros.node_docs import nodes_markdown

    text = nodes_markdown()
    if args.check:
        if args.out is None:
            raise ValueError("--check needs --out")
        current = args.out.read_text() if args.out.is_file() else ""
        if current != text:
            print(f"{args.out} is stale: run `nbv docs nodes --out {args.out}`")
            return 1
        print(f"{args.out} is up to date")
        return 0
    if args.out is None:
        print(text, end="")
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0
