"""Numeric CSV tables, read line by line and converted in chunks (no per-cell Python objects are kept).

A file is a header of column names and rows of numbers: plain decimal or scientific notation with ASCII digits
(``units.plain_number``; integer columns take integers only), finite. Blank lines, lines of empty cells and
lines whose first cell starts with ``#`` are skipped; line numbers count every line of the file (header =
its line). A row that is not plain numbers separated by commas (quoted cells, other spacing) is read by the
``csv`` module, cell by cell. Every problem is a one-line DataFormatError naming file, line and column, quoting
at most the offending cell, cut short.

Memory: the values (8 bytes per cell) and line numbers (8 bytes per row), plus one chunk of ``CHUNK_LINES``
lines of text while it is converted.
"""

from __future__ import annotations

import csv
import itertools
import re
from pathlib import Path

import numpy as np

from kincal.errors import DataFormatError
from kincal.io import units
from kincal.io.yamlfile import clip, text_lines

CHUNK_LINES = 8192
_NUMBER = r"[ \t]*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?[ \t]*"
_INTEGER = r"[ \t]*[+-]?[0-9]+[ \t]*"


class Table:
    """A numeric CSV: ``header`` (column names), ``values`` (rows, columns), ``lines`` (the file line of each row)
    and ``used`` (the columns taken so far, in order)."""

    def __init__(self, path: Path, header: list[str], header_line: int, values: np.ndarray, lines: np.ndarray):
        self.path, self.header, self.header_line, self.values, self.lines = path, header, header_line, values, lines
        self.col = {c: i for i, c in enumerate(header)}
        self.used: list[str] = []

    def __len__(self) -> int:
        return len(self.lines)

    def take(self, columns: list[str]) -> np.ndarray:
        """The values of ``columns`` (rows, len(columns)); a missing column is an error naming the header line."""
        for c in columns:
            if c not in self.col:
                raise DataFormatError(f"{self.path}: line {self.header_line}, column '{clip(c)}': missing from the "
                                      f"header; found columns: {clip(', '.join(self.header))}")
        self.used += [c for c in columns if c not in self.used]
        return self.values[:, [self.col[c] for c in columns]]


def read_table(path, what: str = "data file", integer=()) -> Table:
    """Read the CSV at ``path``; columns named in ``integer`` must hold integers."""
    path = Path(path)
    with text_lines(path, what) as lines:
        header, header_line = _header(path, lines)
        ints = [c in integer for c in header]
        plain = re.compile(",".join(_INTEGER if i else _NUMBER for i in ints), re.ASCII)
        blocks, numbers = [], []
        while chunk := list(itertools.islice(lines, CHUNK_LINES)):
            text, where = [], []
            for number, line in chunk:
                if not plain.fullmatch(line):
                    fields = _fields(path, number, line)
                    if _skipped(fields):
                        continue
                    line = ",".join(repr(x) for x in _row(path, number, fields, header, ints))
                text.append(line)
                where.append(number)
            if text:
                blocks.append(_convert(path, header, text, where))
                numbers.append(np.array(where, dtype=np.int64))
    if not blocks:
        raise DataFormatError(f"{path}: no data rows after the header (line {header_line})")
    return Table(path, header, header_line, np.concatenate(blocks), np.concatenate(numbers))


def _fields(path: Path, number: int, line: str) -> list[str]:
    try:
        return next(csv.reader([line]), [])
    except csv.Error as exc:
        raise DataFormatError(f"{path}: line {number}: not valid CSV: {clip(str(exc))}") from None


def _skipped(fields: list[str]) -> bool:
    return not fields or not "".join(fields).strip() or fields[0].lstrip().startswith("#")


def _header(path: Path, lines) -> tuple[list[str], int]:
    for number, line in lines:
        fields = _fields(path, number, line)
        if _skipped(fields):
            continue
        header = [f.strip() for f in fields]
        dup = sorted({c for c in header if header.count(c) > 1})
        if dup or "" in header:
            raise DataFormatError(f"{path}: line {number}: header has empty or repeated column names {clip(dup)}")
        return header, number
    raise DataFormatError(f"{path}: no header line (expected column names such as 'left.j1')")


def _row(path: Path, number: int, fields: list[str], header: list[str], ints: list[bool]) -> list:
    """The numbers of a row the fast pattern did not match, or the error naming its first bad cell."""
    if len(fields) < len(header):
        raise DataFormatError(f"{path}: line {number}, column '{clip(header[len(fields)])}': row has {len(fields)} "
                              f"values, the header has {len(header)} columns")
    if len(fields) > len(header):
        raise DataFormatError(f"{path}: line {number}: row has {len(fields)} values, the header has {len(header)} "
                              "columns")
    out = []
    for text, column, integer in zip(fields, header, ints):
        x = units.plain_number(text, integer)
        if x is None:
            text = text.strip()
            what = "an integer" if integer else ("a finite number" if units.overflows(text) else "a number")
            raise DataFormatError(f"{path}: line {number}, column '{clip(column)}': expected {what}, found "
                                  f"{clip(text, 40)!r}")
        out.append(x)
    return out


def _convert(path: Path, header: list[str], text: list[str], where: list[int]) -> np.ndarray:
    """Rows of plain numbers (checked) to an array; a number too large for a float is an error."""
    block = np.loadtxt(text, delimiter=",", dtype=float, comments=None, ndmin=2)
    bad = np.argwhere(~np.isfinite(block))
    if len(bad):
        r, c = bad[0]
        raise DataFormatError(f"{path}: line {where[r]}, column '{clip(header[c])}': expected a finite number, found "
                              f"{clip(text[r].split(',')[c].strip(), 40)!r}")
    return block
