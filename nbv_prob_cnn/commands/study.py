"""``nbv study NAME [args]``: run one of the research studies of a source checkout
(``studies/`` beside this package). The product does not import them: the study runs in its own
Python process, ``python -m studies NAME [args]``, with the checkout on its path."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

NAME = "study"
HELP = "Run a research study of the source checkout (studies/): nbv study NAME [args]; nbv study --list."


def studies_root() -> Path:
    """The checkout that holds ``studies/`` (this package's parent folder)."""
    return Path(__file__).resolve().parents[2]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--list", action="store_true", help="list the studies with one line each")
    parser.add_argument("name", nargs="?", help="the study (a module of studies/)")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="the study's own arguments (NAME --help lists them)")


def run(args: argparse.Namespace) -> int:
    root = studies_root()
    if not (root / "studies" / "__main__.py").is_file():
        raise FileNotFoundError(f"{root / 'studies'}: no studies here; they ship with the source checkout only")
    argv = [] if args.list or not args.name else [args.name, *args.args]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root), *filter(None, [env.get("PYTHONPATH")])])
    return subprocess.run([sys.executable, "-m", "studies", *(argv or ["--help"])], env=env).returncode
