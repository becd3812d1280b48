"""Write files under a temporary name and rename them when complete.

A cancelled or failed run never leaves a half-written output behind, and a command
with several outputs writes them all or none (:func:`atomic_outputs`).
"""

from __future__ import annotations

import contextlib
import contextvars
import itertools
import os
import shutil
import tempfile
import threading
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import FileFormatError
from .progress import Progress

__all__ = ["atomic_output", "atomic_outputs", "check_writable", "new_files_removed_on_failure",
           "committing", "journal_mark", "written_since", "will_exist", "record_written"]


# ---- the journal of committed outputs (what a cancelled command may say it wrote) -------------

_JOURNAL: deque[tuple[int, Path]] = deque(maxlen=10_000)
_SEQ = itertools.count(1)
_JOURNAL_LOCK = threading.Lock()
_COMMITTING = 0  # > 0 while outputs are being renamed into place


def journal_mark() -> int:
    """A mark for :func:`written_since`: outputs committed after it are reported."""
    with _JOURNAL_LOCK:
        return _JOURNAL[-1][0] if _JOURNAL else 0


def written_since(mark: int) -> list[Path]:
    """Outputs committed (renamed into place) after ``mark`` that still exist, in order.

    The command line uses it to say truthfully what an interrupted command left behind.
    """
    with _JOURNAL_LOCK:
        paths = [p for seq, p in _JOURNAL if seq > mark]
    seen: dict[Path, None] = {}
    for p in paths:
        if p.exists():
            seen[p] = None
    return list(seen)


def record_written(paths: list[Path]) -> None:
    """Add complete outputs that other processes committed (e.g. batch workers) to the
    journal, so that an interrupted command names them too."""
    for p in paths:
        _record(Path(p))


def will_exist(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` exists, or is written by the open :func:`atomic_outputs` block."""
    p = Path(path)
    txn = _ACTIVE.get()
    return p.exists() or (txn is not None and p.absolute() in txn.pending)


def committing() -> bool:
    """True while outputs are being renamed into place (do not interrupt that)."""
    return _COMMITTING > 0


@contextlib.contextmanager
def _commit_section() -> Iterator[None]:
    global _COMMITTING
    _COMMITTING += 1
    try:
        yield
    finally:
        _COMMITTING -= 1


def _record(path: Path) -> None:
    with _JOURNAL_LOCK:
        _JOURNAL.append((next(_SEQ), path))


# ---- transactions: several outputs, all or none -----------------------------------------------


@dataclass
class _Transaction:
    """Outputs written inside :func:`atomic_outputs`, renamed only when all succeeded."""

    # absolute final path -> (final path as given, complete temporary file)
    pending: dict[Path, tuple[Path, Path]] = field(default_factory=dict)
    created_dirs: list[Path] = field(default_factory=list)  # outermost first
    existed: set[Path] = field(default_factory=set)  # finals that existed before

    def rollback(self) -> None:
        for _, tmp in self.pending.values():
            _remove(tmp)
        self.pending.clear()
        for d in reversed(self.created_dirs):  # deepest first; only if left empty
            with contextlib.suppress(OSError):
                d.rmdir()

    def commit(self) -> list[Path]:
        done: list[Path] = []
        with _commit_section():
            try:
                for key, (final, tmp) in self.pending.items():
                    os.replace(tmp, key)
                    done.append(final)
            except OSError as exc:
                for done_final in done:  # undo what can be undone: new files go again
                    if done_final.absolute() not in self.existed:
                        _remove(done_final)
                self.rollback()
                raise FileFormatError(f"cannot write {final}: {exc.strerror or exc}; no "
                                      "output of this step was kept") from None
            for final in done:
                _record(final)
        self.pending.clear()
        return done


_ACTIVE: contextvars.ContextVar[_Transaction | None] = contextvars.ContextVar(
    "canopyblocks_atomic_transaction", default=None)


@contextlib.contextmanager
def atomic_outputs(*paths: str | os.PathLike[str], keep_existing: bool = False,
                   progress: Progress | None = None) -> Iterator[tuple[Path, ...]]:
    """Write several outputs as one: every file appears, or none does.

    Yields one temporary path per entry of ``paths`` (as :func:`atomic_output` does for
    one).  Moreover every :func:`atomic_output` opened inside the block, by any writer
    called there (tables, HDF5 files, plots, reports), joins the transaction: its file is
    renamed into place only when the whole block has succeeded.  On any exception,
    including :class:`~canopyblocks.errors.CancelledError`, KeyboardInterrupt and a
    SIGTERM handled as one, every temporary file is removed, folders the block created
    are removed again when left empty, and existing files are untouched.

    Parameters
    ----------
    *paths : path-like
        Files the block writes itself (through the yielded temporary paths).
    keep_existing : bool
        Copy each existing ``path`` to its temporary name first (see :func:`atomic_output`).
    progress : Progress, optional
        Checked once more just before the renames: a cancellation asked while the files
        were being written still leaves nothing behind.

    Notes
    -----
    Inside the block an output is not yet at its final path: a writer that reads back
    what an earlier writer of the same block produced must use the temporary path.  A
    transaction opened inside another joins the outer one.  The renames themselves run
    in a short section that the command line does not interrupt.
    """
    outer = _ACTIVE.get()
    if outer is not None:
        with contextlib.ExitStack() as stack:
            yield tuple(stack.enter_context(atomic_output(p, keep_existing=keep_existing))
                        for p in paths)
        return
    txn = _Transaction()
    token = _ACTIVE.set(txn)
    try:
        with contextlib.ExitStack() as stack:
            tmps = tuple(stack.enter_context(atomic_output(p, keep_existing=keep_existing))
                         for p in paths)
            yield tmps
        if progress is not None:
            progress.check()
    except BaseException:
        _ACTIVE.reset(token)
        txn.rollback()
        raise
    _ACTIVE.reset(token)
    txn.commit()


# ---- one output ---------------------------------------------------------------------------------


def _make_parent(folder: Path, txn: _Transaction | None) -> None:
    missing = []
    p = folder
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    if txn is not None:
        txn.created_dirs.extend(reversed(missing))


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, keep_existing: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path : path-like
        The final file (or directory) name.  Its folder is created if needed.
    keep_existing : bool
        When True, copy an existing ``path`` to the temporary name first, so that a
        writer can add a layer to an existing GeoPackage without touching the
        original until it has finished.

    Notes
    -----
    The temporary name keeps the suffix (drivers pick formats by suffix).  On any
    exception, including :class:`~canopyblocks.errors.CancelledError` and
    KeyboardInterrupt, the temporary file is removed and ``path`` is unchanged.
    Inside :func:`atomic_outputs` the rename waits for the whole transaction.
    """
    from .arguments import check_path
    check_path(path, "atomic_output: path")
    final = Path(path)
    check_writable(final)
    txn = _ACTIVE.get()
    key = final.absolute()
    try:
        _make_parent(final.parent, txn)
        fd, tmpname = tempfile.mkstemp(
            prefix=f".{final.stem}.", suffix=f".part{final.suffix}", dir=final.parent
        )
    except OSError as exc:
        raise FileFormatError(
            f"cannot write {final}: {exc.strerror or exc}; choose a writable folder"
        ) from None
    os.close(fd)
    tmp = Path(tmpname)
    tmp.unlink()  # writers (GDAL, h5py) want to create the file themselves
    try:
        if keep_existing:
            entry = txn.pending.get(key) if txn is not None else None
            source = entry[1] if entry is not None else None
            if source is None and final.exists():
                source = final
            if source is not None:
                _copy(source, tmp)
        yield tmp
    except BaseException:
        _remove(tmp)
        raise
    if not tmp.exists():
        raise FileNotFoundError(f"the writer produced no file for {final}")
    if txn is not None:
        previous = txn.pending.pop(key, None)
        if previous is not None:  # written twice in one transaction: the last one counts
            _remove(previous[1])
        elif final.exists():
            txn.existed.add(key)
        txn.pending[key] = (final, tmp)
        return
    with _commit_section():
        os.replace(tmp, final)
        _record(final)


def _copy(src: Path, dst: Path) -> None:
    try:
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copy2(src, dst)
    except OSError as exc:
        raise FileFormatError(f"cannot copy {src} to update it: {exc.strerror or exc}") from None


def check_writable(path: str | os.PathLike[str], *, folder: bool = False) -> Path:
    """Refuse an output path that cannot be written, before any work is done.

    Parameters
    ----------
    path : path-like
        The output file (or, with ``folder=True``, the output folder).
    folder : bool
        ``path`` is a folder to write into: it must be a folder or not exist.

    Raises
    ------
    FileFormatError
        ``path`` is a folder where a file is expected (or a file where a folder is),
        one of its parents is a file, or its nearest existing parent is not writable.
    """
    p = Path(path)
    if folder and p.exists() and not p.is_dir():
        raise FileFormatError(f"output folder {p} is a file; give a folder name")
    if not folder and p.is_dir():
        raise FileFormatError(f"output {p} is a folder; give a file name")
    parent = p if folder else p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise FileFormatError(f"cannot write {p}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise FileFormatError(f"cannot write {p}: folder {parent} is not writable; "
                              "choose a writable folder")
    return p


def _remove(p: Path) -> None:
    if p.is_dir():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
    # GDAL/SQLite side files
    for side in (p.with_name(p.name + "-journal"), p.with_name(p.name + "-wal"),
                 p.with_name(p.name + "-shm"), p.with_name(p.name + ".aux.xml")):
        with contextlib.suppress(FileNotFoundError):
            side.unlink()


@contextlib.contextmanager
def new_files_removed_on_failure(folder: str | os.PathLike[str]) -> Iterator[None]:
    """On any failure (bad input, cancellation, Ctrl-C) remove what this run wrote.

    Files and folders under ``folder`` that did not exist when the run started are
    deleted, and ``folder`` itself when the run created it; older files are kept.  Each
    output is written atomically, so a survivor is never half-written, but a failed
    run must not leave a half-finished set of outputs that looks like a result.
    """
    out = Path(folder)
    created = not out.exists()
    top = out  # the outermost folder this run will create
    while not top.parent.exists() and top.parent != top.parent.parent:
        top = top.parent
    before = set() if created else set(out.rglob("*"))
    try:
        yield
    except BaseException:
        if created:
            shutil.rmtree(top, ignore_errors=True)
        else:
            new = sorted((p for p in out.rglob("*") if p not in before),
                         key=lambda p: len(p.parts), reverse=True)
            for p in new:  # deepest first, so folders are empty when reached
                with contextlib.suppress(OSError):
                    if p.is_dir() and not p.is_symlink():
                        p.rmdir()
                    else:
                        p.unlink()
        raise
