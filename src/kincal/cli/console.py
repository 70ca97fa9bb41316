"""The console every command prints to: tables that fit the terminal without cutting a number.

rich shrinks a table wider than the terminal by cutting cells to ``0.00…``. ``FittingConsole`` prints such a
table as several narrower ones instead (the first column repeated in each, the title marked "continued"),
each column as wide as its longest number or word (headers wrap), and folds (never cuts) long names. The width is the terminal's, or ``COLUMNS`` when set, or
200 when the output is not a terminal (a file or a pipe keeps whole rows).
"""

from __future__ import annotations

import os
import re

from rich.console import Console
from rich.progress import ProgressColumn
from rich.table import Table
from rich.text import Text

PIPE_WIDTH = 200


class FittingConsole(Console):
    """A rich Console whose ``print`` splits tables too wide for it by columns."""

    def print(self, *objects, **kwargs) -> None:  # noqa: A003  (rich's name)
        out = []
        for o in objects:
            out.extend(fit_table(self, o) if isinstance(o, Table) else [o])
        super().print(*out, **kwargs)


def make_console(**kwargs) -> FittingConsole:
    """A FittingConsole (kwargs as rich's Console), 200 columns wide on a pipe unless COLUMNS says otherwise."""
    console = FittingConsole(**kwargs)
    if console.is_terminal or os.environ.get("COLUMNS") or "width" in kwargs:
        return console
    return FittingConsole(width=PIPE_WIDTH, **kwargs)


def fit_table(console: Console, table: Table) -> list[Table]:
    """``table`` if it fits ``console`` as it is, else tables of its first column and as many of the others as
    fit, each column as wide as its longest word or number (headers wrap; numbers are never cut)."""
    for col in table.columns:
        col.overflow = "fold"  # whatever still does not fit is folded onto the next line, never cut
    if _natural(console, table) <= console.width or len(table.columns) < 3:
        return [table]
    needs = [_needed(c) for c in table.columns]
    fits = lambda cols: _natural(console, _part(table, [0] + cols, needs, "")) <= console.width  # noqa: E731
    groups, current = [], []
    for i in range(1, len(table.columns)):
        if current and not fits(current + [i]):
            groups.append(current)
            current = []
        current.append(i)
    groups.append(current)
    balanced = _balanced(needs, len(groups))
    if all(fits(g) for g in balanced):
        groups = balanced  # as many parts, of even widths (no part of one leftover column)
    title = str(table.title) if table.title else ""
    more = title.split(" (")[0] + " (continued)" if title else ""
    return [_part(table, [0] + g, needs, title if k == 0 else more) for k, g in enumerate(groups)]


def _balanced(needs: list[int], parts: int) -> list[list[int]]:
    """Columns 1.. in ``parts`` contiguous groups of about equal width."""
    total = sum(needs[1:]) + 3 * (len(needs) - 1)
    groups, current, done = [], [], 0
    for i in range(1, len(needs)):
        if current and done + needs[i] / 2 > total * (len(groups) + 1) / parts:
            groups.append(current)
            current = []
        current.append(i)
        done += needs[i] + 3
    return groups + [current]


def _natural(console: Console, table: Table) -> int:
    """The width ``table`` takes when nothing limits it."""
    return console.measure(table, options=console.options.update_width(100_000)).maximum


# A number (or a dash for none, a percentage): a cell token that must never be cut.
_NUMBER = re.compile(r"^[-+(]?(\d[\d.,]*([eE][-+]?\d+)?%?|inf|nan|-)\)?$")
TEXT_TOKEN_CAP = 30  # longer names (data set labels) fold at this width when the table must be narrow


# A cell of numbers only (a vector "(0, 0.1273, 0)", a range "-360.00 .. 360.00 deg"): kept on one line.
_NUMBERS = re.compile(r"^[-+\d.,eE()\[\]\s]*\d[-+\d.,eE()\[\]\s]*(deg|rad|mm|m|%)?$")
NUMBERS_CAP = 40  # longer rows of numbers wrap between them


def _needed(column) -> int:
    """The width of the column's longest word: numbers whole (a cell of numbers whole up to NUMBERS_CAP),
    names up to TEXT_TOKEN_CAP."""
    cells = [c.plain if isinstance(c, Text) else str(c) for c in column._cells]
    tokens = [t for text in [str(column.header)] + cells for t in text.split()] or [""]
    whole = [len(c) for c in cells if len(c) <= NUMBERS_CAP and _NUMBERS.match(c)]
    longest = max(len(t) if _NUMBER.match(t) else min(len(t), TEXT_TOKEN_CAP) for t in tokens)
    return max([1, longest] + whole)


def _part(table: Table, columns: list[int], widths: list[int], title: str) -> Table:
    t = Table(title=title or None, box=table.box, show_header=table.show_header, header_style=table.header_style,
              title_style=table.title_style, show_lines=table.show_lines)
    for i in columns:
        c = table.columns[i]
        t.add_column(c.header, justify=c.justify, style=c.style, header_style=c.header_style, overflow="fold",
                     width=widths[i])
    for r in range(table.row_count):
        t.add_row(*[table.columns[i]._cells[r] for i in columns])
    return t


class CountColumn(ProgressColumn):
    """``done/total``, or ``done`` alone while the total is not known yet (never "None")."""

    def render(self, task) -> Text:
        done = int(task.completed)
        return Text(f"{done}/{int(task.total)}" if task.total is not None else f"{done}")
