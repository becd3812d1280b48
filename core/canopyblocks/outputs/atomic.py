"""Write files under a temporary name and rename them when complete.

A cancelled or failed run never leaves a half-written output behind.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import FileFormatError

__all__ = ["atomic_output", "check_writable", "new_files_removed_on_failure"]


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
    """
    final = Path(path)
    check_writable(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
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
    if keep_existing and final.exists():
        shutil.copy2(final, tmp)
    try:
        yield tmp
    except BaseException:
        _remove(tmp)
        raise
    if not tmp.exists():
        raise FileNotFoundError(f"the writer produced no file for {final}")
    os.replace(tmp, final)


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
