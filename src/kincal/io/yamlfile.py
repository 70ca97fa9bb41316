"""Reading text and YAML files safely, with errors that name the file, line and column.

Text: only regular files, at most ``MAX_TEXT_BYTES``; UTF-8, with or without a byte-order mark, or UTF-16 with
its mark (a spreadsheet's "Unicode text" export). Anything else is refused with the byte offset of the first
byte that is not UTF-8.

YAML: ``yaml.safe_load`` semantics, stricter where a silent surprise would hurt: a key repeated in one mapping
is an error (the last one would win); an alias (``*name``) may not refer to a value that contains it (a
recursive value), and a document may not expand to more than ``MAX_YAML_NODES`` values with its aliases
written out (an "alias bomb"); exponent floats without a dot (``1e-3``) are numbers, not strings (YAML 1.1
reads them as strings).
"""

from __future__ import annotations

import codecs
import contextlib
import io
import re
import stat
from pathlib import Path

import yaml

from kincal.errors import DataFormatError

MAX_TEXT_BYTES = 512 * 2**20  # a text file larger than this is refused before it is read
MAX_YAML_NODES = 1_000_000  # values in one YAML document with every alias written out
MAX_QUOTE = 80  # characters of a file's content an error message quotes at most


class _Loader(yaml.SafeLoader):
    """SafeLoader without recursive aliases, alias bombs and duplicate keys, with YAML 1.2 exponent floats."""

    def compose_node(self, parent, index):
        open_anchors = self.__dict__.setdefault("_open_anchors", [])
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) and event.anchor in open_anchors:
            raise yaml.composer.ComposerError(
                None, None, f"alias *{event.anchor} refers to a value that contains it (a recursive value)",
                event.start_mark)
        anchor = getattr(event, "anchor", None) if not isinstance(event, yaml.AliasEvent) else None
        open_anchors.append(anchor)
        try:
            return super().compose_node(parent, index)
        finally:
            open_anchors.pop()

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None and _expanded_size(node, {}) > MAX_YAML_NODES:
            raise yaml.composer.ComposerError(
                None, None, f"the document expands to more than {MAX_YAML_NODES} values through its aliases",
                node.start_mark)
        return node

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.setdefault(key, key_node.start_mark)
            except TypeError:  # an unhashable key: safe_load refuses it below
                continue
            if first is not key_node.start_mark:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {quote(key)} appears twice in one mapping (first on line {first.line + 1})",
                    key_node.start_mark)
        return super().construct_mapping(node, deep)


def _expanded_size(node, memo: dict) -> int:
    """Number of values under ``node`` with aliases written out (a shared node counts at every use)."""
    key = id(node)
    if key not in memo:
        memo[key] = 0  # a cycle (refused while composing) would count once
        if isinstance(node, yaml.SequenceNode):
            memo[key] = 1 + sum(_expanded_size(n, memo) for n in node.value)
        elif isinstance(node, yaml.MappingNode):
            memo[key] = 1 + sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
        else:
            memo[key] = 1
        memo[key] = min(memo[key], MAX_YAML_NODES + 1)  # stop growing once past the limit
    return memo[key]


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)?(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_yaml(text: str, file: str):
    """Parse ``text`` (see the module docstring); a problem becomes a DataFormatError naming file, line, column."""
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise DataFormatError(f"{file}: not valid YAML{where}: {clip(problem, 2 * MAX_QUOTE)}") from None
    except ValueError as exc:  # PyYAML's scanner lets a few escapes through, e.g. "\U" beyond U+10FFFF
        raise DataFormatError(f"{file}: not valid YAML: {str(exc).splitlines()[0][:100]}") from None


def decode(raw: bytes, file: str) -> str:
    """Text of a file's bytes: UTF-8 (a byte-order mark is dropped) or UTF-16 with its byte-order mark."""
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError as exc:
            raise DataFormatError(f"{file}: not valid UTF-16 text at byte {exc.start}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFormatError(
            f"{file}: not UTF-8 text: byte 0x{raw[exc.start]:02x} at offset {exc.start}; save the file as UTF-8"
        ) from None


def clip(text: str, limit: int = MAX_QUOTE) -> str:
    """``text`` as an error message may quote it: one line, at most ``limit`` characters."""
    text = str(text).replace("\r", " ").replace("\n", " ")
    return text if len(text) <= limit else text[: limit - 3] + "..."


def quote(x) -> str:
    """``repr(x)`` as an error message may quote it (``clip``): never more of a file than a short line."""
    return clip(repr(x))


def shown(path) -> str:
    """A path as an error message names it: as it is, or quoted where it holds characters that would break the
    message's one line (a newline, a NUL, other control characters)."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def _checked(path, what: str) -> Path:
    """``path`` if it names a regular file no larger than ``MAX_TEXT_BYTES``, else a DataFormatError."""
    path = Path(path)
    if "\0" in str(path):
        raise DataFormatError(f"{shown(path)}: cannot read {what}: the file name contains a NUL character")
    try:
        info = path.stat()
    except OSError as exc:
        raise DataFormatError(f"{shown(path)}: cannot read {what}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise DataFormatError(f"{shown(path)}: cannot read {what}: not a regular file")
    if info.st_size > MAX_TEXT_BYTES:
        raise DataFormatError(f"{shown(path)}: cannot read {what}: {info.st_size} bytes, more than the limit of "
                              f"{MAX_TEXT_BYTES} bytes")
    return path


def read_text(path, what: str) -> str:
    """The text of ``path``; ``what`` says which kind of file it should be (for the error)."""
    path = _checked(path, what)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    return decode(raw, str(path))


@contextlib.contextmanager
def text_lines(path, what: str):
    """The lines of ``path`` (a regular file, decoded as ``read_text`` does) one at a time, numbered from 1, without
    reading the whole file into memory; line ends are ``\\n``, ``\\r\\n`` or ``\\r``, and are dropped."""
    path = _checked(path, what)
    try:
        with open(path, "rb") as raw:
            utf16 = raw.read(2) in (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)
            raw.seek(0)
            text = io.TextIOWrapper(raw, encoding="utf-16" if utf16 else "utf-8-sig", newline=None)
            try:
                yield ((i, line.rstrip("\n")) for i, line in enumerate(text, 1))
            except UnicodeDecodeError:
                read_text(path, what)  # reads the whole file again for the error naming the byte offset
                raise DataFormatError(f"{path}: cannot read {what}: not UTF-8 or UTF-16 text") from None
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None


def read_yaml(path, what: str):
    """Read and parse a YAML file."""
    return parse_yaml(read_text(path, what), str(path))
