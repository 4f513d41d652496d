"""The pages and docstrings refer only to what a clone of the repository holds: no section of the
method specification kept outside it ("SPEC §2"), not the specification or the paper's text
themselves (``SPEC.md``, ``paper.txt``), no markdown page, text file or relative link that is not in the
repository. Scanned: every markdown page (README.md, docs/, studies/, bags/) and the module,
class and function docstrings of nbv_prob_cnn/ and studies/."""

from __future__ import annotations

import ast
import os
import re
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: Folders of the checkout that are not the repository's (environments, build and run outputs).
SKIPPED = {".git", ".venv", "build", "install", "log", "cache", "out", ".benchmarks"}
#: The specification and the paper's text live beside the repository, not in it (a data set's
#: download may too: an example path to it is no reference to a file of the repository).
OUTSIDE = re.compile(r"\bSPEC\b|\bpaper\.(?:txt|pdf|md)\b")
#: A file name that a page or docstring may name as a file of the repository.
FILE_NAME = re.compile(r"[\w.-]*\w\.(?:md|txt|pdf)\b")
#: Files of the RGB-D recordings' formats (7-Scenes, TUM RGB-D) that the importer reads: named
#: where the formats are described, part of the downloaded data, never of the repository.
RECORDING_FILES = {
    "camera-intrinsics.txt", "depth.txt", "frame-NNNNNN.pose.txt", "gravity-direction.txt", "groundtruth.txt",
}  # fmt: skip
LINK = re.compile(r"\]\(([^)\s]+)\)")


def repository_files() -> list[Path]:
    """The files of the checkout, without :data:`SKIPPED` and hidden folders (not walked into)."""
    found = []
    for folder, subfolders, files in os.walk(REPO):
        subfolders[:] = [d for d in subfolders if not (d in SKIPPED or d.startswith(".") or d.endswith(".egg-info"))]
        found += [Path(folder) / f for f in files]
    return found


def texts() -> Iterator[tuple[str, int, str]]:
    """``(file, first line, text)`` of every markdown page and every docstring of the code."""
    for path in repository_files():
        name = str(path.relative_to(REPO))
        if path.suffix == ".md":
            yield name, 1, path.read_text(errors="replace")
        elif path.suffix == ".py" and name.startswith(("nbv_prob_cnn/", "studies/")):
            yield from docstrings(name, path.read_text())


def docstrings(name: str, source: str) -> Iterator[tuple[str, int, str]]:
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            text = ast.get_docstring(node, clean=False)
            if text:
                yield name, node.body[0].lineno, text


def outside_references(text: str) -> list[re.Match[str]]:
    return list(OUTSIDE.finditer(text))


def missing_file_names(text: str, present: set[str]) -> list[re.Match[str]]:
    return [
        m
        for m in FILE_NAME.finditer(text)
        if Path(m.group(0)).name not in present and m.group(0) not in RECORDING_FILES
    ]


def where(name: str, first_line: int, text: str, found: re.Match[str]) -> str:
    line = first_line + text[: found.start()].count("\n")
    return f"{name}:{line}: {found.group(0)!r}"


def test_the_checks_find_what_they_look_for() -> None:
    found = outside_references("as SPEC §2 says,\nsee SPEC.md or ../shared/paper.txt")
    assert [m.group(0) for m in found] == ["SPEC", "SPEC", "paper.txt"]
    assert where("x.md", 10, "as SPEC §2 says,\nsee SPEC.md", found[1]) == "x.md:11: 'SPEC'"
    assert outside_references("DATASET_SPECS, SPEC_LEARNING_RATE and the param spec") == []
    present = {"README.md", "ros.md"}
    missing = missing_file_names("see ros.md, notes.md and depth.txt", present)
    assert [m.group(0) for m in missing] == ["notes.md"]


def test_no_reference_to_the_project_folder_outside_the_repository() -> None:
    found = [where(*t, ref) for t in texts() for ref in outside_references(t[2])]
    assert not found, "refers to files that are not in the repository:\n" + "\n".join(found)


def test_named_pages_and_text_files_are_in_the_repository() -> None:
    present = {p.name for p in repository_files()}
    found = [where(*t, n) for t in texts() for n in missing_file_names(t[2], present)]
    assert not found, "names files that are not in the repository:\n" + "\n".join(found)


def test_every_relative_link_of_every_page_resolves() -> None:
    broken = []
    for page in (p for p in repository_files() if p.suffix == ".md"):
        for target in LINK.findall(page.read_text(errors="replace")):
            path = target.split("#")[0]
            if path and not re.match(r"[a-z]+:", path) and not (page.parent / path).exists():
                broken.append(f"{page.relative_to(REPO)}: {target}")
    assert not broken, "links to files that are not in the repository:\n" + "\n".join(broken)
