"""The report's number cells, read back from its HTML and compared with the files they show."""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import pytest

from microcal.report import load_run


class Cells(HTMLParser):
    """Collects the report's number cells (data-key, data-value, text) and its images."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[tuple[str, str, str]] = []
        self.images: list[str] = []
        self._open: tuple[str, str] | None = None
        self._text = ""

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "td" and "data-key" in a:
            self._open, self._text = (a["data-key"], a["data-value"]), ""
        if tag == "img":
            self.images.append(a.get("src", ""))

    def handle_data(self, data):
        if self._open:
            self._text += data

    def handle_endtag(self, tag):
        if tag == "td" and self._open:
            self.cells.append((*self._open, self._text.strip()))
            self._open = None


def cells(path: Path) -> Cells:
    parser = Cells()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def lookup(data, key: str):
    for part in key.split("."):
        data = data[int(part)] if isinstance(data, list) else data[part]
    return data


def check_number_cells(out: Path, page: Path) -> set[str]:
    """Every number cell of the report ``page`` equals the file of ``out`` its key names.

    Returns the keys checked.
    """
    parsed = cells(page)
    sources = {
        "results": json.loads((out / "results.json").read_text()),
        "cameras": json.loads((out / "cameras.json").read_text())["cameras"],
        "calibration": {
            e.model.kind: e.validation.model_dump() if e.validation is not None else {}
            for e in load_run(out).model_errors()  # matrix and polynomial, each its own
        },
    }
    checked = set()
    for key, value, text in parsed.cells:
        head, _, rest = key.partition(".")
        if head in ("cameras", "calibration"):
            expected = lookup(sources[head], rest)
        else:
            expected = lookup(sources["results"], key)
        assert float(value) == pytest.approx(expected, rel=1e-12, abs=1e-12), key
        digits = len(text.split(".")[1]) if "." in text else 0
        assert text == f"{expected:.{digits}f}", key
        checked.add(key)
    return checked
