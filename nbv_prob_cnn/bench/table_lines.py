"""The lines of a benchmark table that also go out one by one as they are measured, so a suite that runs
for a minute shows its rows while it runs (``nbv bench --suite cnn``)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

#: Where each line goes as soon as it exists (e.g. ``print`` with ``flush=True``).
Echo = Callable[[str], None]


class EchoedLines(list):
    """A list of lines that hands each appended line to ``echo`` too (``None``: a plain list)."""

    def __init__(self, lines: Iterable[str], echo: Echo | None) -> None:
        super().__init__()
        self._echo = echo
        for line in lines:
            self.append(line)

    def append(self, line: str) -> None:
        super().append(line)
        if self._echo is not None:
            self._echo(line)
