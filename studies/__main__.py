"""``python -m studies NAME [args]``: run one study (what ``nbv study NAME [args]`` calls)."""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def study_names() -> dict[str, str]:
    """Every study module (one with a ``main``) and the first line of its docstring, read without
    importing it."""
    found: dict[str, str] = {}
    for path in sorted(HERE.glob("*.py")):
        if path.stem.startswith("_"):
            continue
        tree = ast.parse(path.read_text())
        if any(isinstance(node, ast.FunctionDef) and node.name == "main" for node in tree.body):
            found[path.stem] = (ast.get_docstring(tree) or "").strip().split("\n")[0]
    return found


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    names = study_names()
    if not args or args[0] in ("-h", "--help"):
        print("usage: nbv study NAME [args]   (nbv study NAME --help: the study's own options)\n\nstudies:")
        for name, line in names.items():
            print(f"  {name:<20} {line}")
        return 0 if args else 2
    name = args[0]
    if name not in names:
        print(f"nbv study: error: no study {name!r}; one of: {', '.join(names)}", file=sys.stderr)
        return 2
    module = importlib.import_module(f"studies.{name}")
    sys.argv[0] = f"nbv study {name}"  # argparse's prog in the study's usage lines
    try:
        return int(module.main(args[1:]) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"nbv study {name}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
