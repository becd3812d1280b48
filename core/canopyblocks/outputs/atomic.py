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

__all__ = ["atomic_output"]


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
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, tmpname = tempfile.mkstemp(
        prefix=f".{final.stem}.", suffix=f".part{final.suffix}", dir=final.parent
    )
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
