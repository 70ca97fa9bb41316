"""All-or-nothing outputs: write into a temporary folder (or file) beside the target, move it into place at the end.

``output_directory(target)`` yields a ``Staging`` whose ``path`` is a fresh folder on the target's file system;
the caller writes there as if it were ``target``. On a normal exit the files are flushed to disk (fsync) and
moved into place by renames; on any exception (KeyboardInterrupt from SIGINT included) the temporary folder is
removed and the target is left as it was. ``output_file(target)`` does the same for one file.

- A new target folder appears whole by one rename of the temporary folder.
- An existing target folder receives the new entries one rename each; the ``last`` entry (the report or
  manifest that says the output is complete) is moved out first when replaced and moved in last, so it is never
  there without the rest. With ``overwrite`` an old entry is replaced only then, never deleted first.
- SIGINT and SIGTERM are held back while moving and cleaning up; a process killed outright (SIGKILL) can leave
  only a temporary named ``.<target>.kincal-tmp-<pid>-<random>`` (beside a new target) or
  ``<target>/.kincal-tmp-<pid>-<random>``, never a cut-off file under a final name. Later runs delete such
  temporaries once the process that made them is gone. Format and meaning: docs/formats.md "Outputs".
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import signal
import threading
from contextlib import contextmanager
from pathlib import Path

from kincal.errors import DataFormatError

TAG = ".kincal-tmp-"
_HELD = {signal.SIGINT, signal.SIGTERM}


class Staging:
    """Where to write (``path``) and where it will be (``target``); ``final(p)`` maps a written path to its
    place after the move. A handle with state, not a value: ``created`` lists what the move added (for
    ``undo``), ``keep`` says a failed move could not be undone and the temporary holds the previous output."""

    def __init__(self, path: Path, target: Path):
        self.path, self.target = path, target
        self.created: list[Path] = []
        self.keep = False

    def final(self, p) -> Path:
        return self.target / Path(p).relative_to(self.path)

    def undo(self) -> None:
        """Remove what the move added (the whole target if it made it): an output of several steps that failed
        after this one. Files it replaced are not brought back."""
        with _held_signals():
            for p in reversed(self.created):
                _remove(p)


@contextmanager
def _held_signals():
    """SIGINT and SIGTERM wait until the block is done: handlers that only note the signal, then the previous
    handlers and the signal raised again. Python runs signal handlers in the main thread whichever thread the
    system delivers a signal to (BLAS worker threads included), which a thread signal mask would not cover;
    outside the main thread nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {s: signal.getsignal(s) for s in _HELD}
    for s in _HELD:
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        if pending:
            signal.raise_signal(pending[0])  # now, to the handler that was in place


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        p.unlink(missing_ok=True)


def _temp_name(prefix: str) -> str:
    return f"{prefix}{TAG}{os.getpid()}-{secrets.token_hex(4)}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists but belongs to someone else
        return True
    return True


def clean_stale(folder: Path, prefix: str) -> None:
    """Delete temporaries ``<prefix>.kincal-tmp-<pid>-*`` in ``folder`` left by processes that no longer run."""
    pattern = re.compile(re.escape(prefix + TAG) + r"(\d+)-[0-9a-f]+$")
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        m = pattern.match(name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            _remove(folder / name)


def _fsync_tree(root: Path) -> None:
    """Flush every file and folder under ``root`` to disk, so a rename never publishes unwritten data."""
    for folder, _, files in os.walk(root):
        for name in files:
            _fsync(Path(folder) / name)
        _fsync(Path(folder))


def _fsync(p: Path) -> None:
    try:
        fd = os.open(p, os.O_RDONLY)
    except OSError:  # folders cannot be opened on some systems; nothing to flush there
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and missing ancestors; return those made (outermost first) so failure can remove them."""
    if folder.exists() and not folder.is_dir():
        raise DataFormatError(f"{folder}: exists and is not a directory; expected a folder for the output")
    missing = []
    p = folder
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFormatError(f"{folder}: cannot create output directory: {exc.strerror or exc}") from None
    return missing[::-1]


def _remove_empty(folders: list[Path]) -> None:
    for p in reversed(folders):
        try:
            p.rmdir()
        except OSError:
            return


def _refuse(target: Path, names) -> None:
    existing = [str(target / n) for n in names if os.path.lexists(target / n)]
    if existing:
        raise DataFormatError(f"{', '.join(existing)}: file exists; not overwritten "
                              "(choose another output directory or pass --overwrite)")


@contextmanager
def output_directory(target, *, names=(), overwrite: bool = False, last: str | None = None, inside_ok: bool = True):
    """Stage an output folder: yields a ``Staging``; see the module docstring.

    ``names``: the entries this command writes; without ``overwrite`` the call refuses (before anything is
    written) if one exists in ``target``, and with it those entries are replaced (removed if this run does
    not write them). ``last``: the entry moved into place last. The temporary is a sibling of ``target`` (so
    paths relative to the output stay right); ``inside_ok``: if the parent refuses it or lies on another
    file system, an existing ``target`` may hold it instead (only for outputs that hold no relative paths)."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise DataFormatError(f"{target}: exists and is not a directory; expected an output directory")
    if not overwrite:
        _refuse(target, names)
    made, stage = _make_parents(target.parent), None
    try:
        with _held_signals():  # an interrupt held back here arrives when released, inside this ``try``
            stage = _new_stage(target, inside_ok)
        yield stage
        with _held_signals():
            _commit(stage, names, overwrite, last)
    except BaseException:
        with _held_signals():
            if stage is not None and not stage.keep:
                _remove(stage.path)
            _remove_empty(made)
        raise


def _new_stage(target: Path, inside_ok: bool) -> Staging:
    """A fresh temporary folder beside ``target`` or, failing that and if allowed, inside an existing one."""
    where = Path(os.path.abspath(target))  # "." has no name; its absolute spelling has
    clean_stale(where.parent, f".{where.name}")
    same_device = not target.is_dir() or os.stat(target).st_dev == os.stat(where.parent).st_dev
    try:
        if not same_device:
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV))
        stage = Staging(where.parent / _temp_name(f".{where.name}"), target)
        stage.path.mkdir()
        return stage
    except OSError as exc:
        if not (inside_ok and target.is_dir()):
            raise DataFormatError(f"{where.parent}: cannot create the temporary output folder beside {where.name}: "
                                  f"{exc.strerror or exc}") from None
    clean_stale(target, "")
    stage = Staging(target / _temp_name(""), target)
    try:
        stage.path.mkdir()
    except OSError as exc:
        raise DataFormatError(f"{target}: cannot write to the output directory: {exc.strerror or exc}") from None
    return stage


def _commit(stage: Staging, names, overwrite: bool, last: str | None) -> None:
    _fsync_tree(stage.path)
    target = stage.target
    if not target.exists():
        try:
            os.rename(stage.path, target)
            stage.created.append(target)
            _fsync(target.parent)
            return
        except OSError:  # made meanwhile by someone else: merge below
            pass
    new = sorted(n for n in os.listdir(stage.path) if n != ".old")
    new.sort(key=lambda n: n == last)
    if not overwrite:
        _refuse(target, new)
    old = [n for n in dict.fromkeys(list(names) + new) if os.path.lexists(target / n)]
    old.sort(key=lambda n: n != last)  # the completion marker leaves first
    _move_in(stage, old, new)


def _move_in(stage: Staging, old: list[str], new: list[str]) -> None:
    """Move replaced entries into the stage's ``.old`` and new ones into the target; undo all on failure."""
    backup, done = stage.path / ".old", []
    try:
        if old:
            backup.mkdir()
        for n in old:
            os.rename(stage.target / n, backup / n)
            done.append((backup / n, stage.target / n))
        for n in new:
            os.rename(stage.path / n, stage.target / n)
            done.append((stage.target / n, stage.path / n))
            stage.created.append(stage.target / n)
    except OSError as exc:
        stage.created.clear()
        if not _put_back(done):  # never delete the previous output: leave it where it is, and say where
            stage.keep = True
            raise DataFormatError(f"{stage.target}: cannot move the output into place: {exc.strerror or exc}; "
                                  f"the previous output is in {backup}") from None
        raise DataFormatError(f"{stage.target}: cannot move the output into place: {exc.strerror or exc}") from None
    _fsync(stage.target)
    _remove(stage.path)


def _put_back(done: list[tuple[Path, Path]]) -> bool:
    """Undo the moves done, last first; False if one of them failed too."""
    ok = True
    for moved, origin in reversed(done):
        try:
            os.rename(moved, origin)
        except OSError:
            ok = False
    return ok


@contextmanager
def output_file(target, *, overwrite: bool = False):
    """Stage one output file: yields the temporary path to write; it replaces ``target`` at the end."""
    target = Path(target)
    if target.is_dir():
        raise DataFormatError(f"{target}: is a directory; expected an output file")
    if not overwrite and os.path.lexists(target):
        raise DataFormatError(f"{target}: exists; refusing to overwrite it (pass --overwrite)")
    made = _make_parents(target.parent)
    prefix = f".{target.name}"
    clean_stale(target.parent, prefix)
    temp = target.parent / _temp_name(prefix)
    try:
        yield temp
        with _held_signals():
            _fsync(temp)
            if not overwrite and os.path.lexists(target):
                raise DataFormatError(f"{target}: exists; refusing to overwrite it (pass --overwrite)")
            os.replace(temp, target)
            _fsync(target.parent)
    except BaseException:
        with _held_signals():
            _remove(temp)
            _remove_empty(made)
        raise
