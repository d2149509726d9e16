"""What a report promises, checked against what its run wrote: every file it names, every section it refers to.

:func:`promised_files` reads the file names a report shows (in ``<code>``
elements: captions, the Run section, the text) and :func:`missing_files`
says which of them the output folder lacks; :func:`section_numbers` and
:func:`dangling_sections` do the same for "section N". Helpers of the report
tests (``test_report_files.py``, ``test_reports_in_browser.py``).
"""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

#: File types a report may name.
EXTENSIONS = ("png", "svg", "csv", "json", "toml", "html", "xlsx")
_FILE = re.compile(r"(?<![\w/.-])(/?[\w.+-]+(?:/[\w.+-]+)*\.(?:" + "|".join(EXTENSIONS) + r"))(?![\w])")


class _Reader(HTMLParser):
    """Text of ``<code>`` elements, ``<h2>`` titles, ``<img alt>`` and the whole text."""

    def __init__(self):
        super().__init__()
        self.code, self.h2, self.alts, self.text = [], [], [], []
        self._in: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag in ("code", "h2"):
            self._in.append(tag)
            getattr(self, tag).append("")
        if tag == "img":
            self.alts.append(dict(attrs).get("alt", ""))

    def handle_endtag(self, tag):
        if self._in and self._in[-1] == tag:
            self._in.pop()

    def handle_data(self, data):
        self.text.append(data)
        for tag in set(self._in):
            getattr(self, tag)[-1] += data


def read(html: str) -> _Reader:
    reader = _Reader()
    reader.feed(html)
    return reader


def promised_files(html: str) -> list[str]:
    """The file names the report shows in ``<code>`` (``figures/x.png``, ``summary.json``, absolute input paths)."""
    return sorted({m for code in read(html).code for m in _FILE.findall(code)})


def missing_files(html: str, folder: Path) -> list[str]:
    """The files the report names that do not exist.

    An absolute path (an input file) must exist; a path with a folder
    (``figures/x.png``) must exist under ``folder``; a bare name must exist
    somewhere in ``folder`` (``geometry.toml`` in ``model/``).
    """
    folder = Path(folder)
    present = {p.name for p in folder.rglob("*") if p.is_file()}
    missing = []
    for name in promised_files(html):
        if name.startswith("/"):
            ok = Path(name).is_file()
        elif "/" in name:
            ok = (folder / name).is_file()
        else:
            ok = name in present
        if not ok:
            missing.append(name)
    return missing


def section_numbers(html: str) -> list[int]:
    """The numbers of the numbered ``<h2>`` sections, in order."""
    return [int(m.group(1)) for t in read(html).h2 if (m := re.match(r"\s*(\d+)\.", t))]


def dangling_sections(html: str) -> list[str]:
    """References "section N" in the text to a section the report does not have."""
    numbers = set(section_numbers(html))
    text = " ".join(read(html).text)
    return [m.group(0) for m in re.finditer(r"\bsections? (\d+)", text) if int(m.group(1)) not in numbers]


def figures_without_files(html: str, folder: Path, ext: str = "png") -> list[str]:
    """Embedded figures (their ``alt`` is the figure's name) with no ``figures/NAME.ext`` or ``NAME.ext`` file."""
    folder = Path(folder)
    return [a for a in read(html).alts
            if not ((folder / "figures" / f"{a}.{ext}").is_file() or (folder / f"{a}.{ext}").is_file())]
