"""What a batch leaves behind: an output folder apart from its inputs, no partial files
after an interruption or on a rerun, no temporary folders, and a true account of the
complete outputs an interrupted batch kept.

Units write their outputs atomically (``.<name>.<random>.part<suffix>`` beside the final
file, renamed when complete).  A worker killed before its clean-up ran (a Dask worker, or
any worker at SIGKILL) leaves such a file; a batch removes them when it ends, however it
ends, and when it starts (a rerun after a killed batch).  Workers make their temporary
files in a folder the batch owns (:func:`private_tempdir`), removed at the end.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from ...errors import InputError

__all__ = ["refuse_output_in_inputs", "remove_partial_outputs", "complete_outputs",
           "private_tempdir"]

log = logging.getLogger(__name__)


def refuse_output_in_inputs(out: Path, inputs: Sequence[str | os.PathLike[str]]) -> None:
    """Refuse an output folder that is an input folder or lies inside one.

    A batch writes rasters, partitions and a manifest there; a rerun would then list
    its own outputs among the inputs (and the user's folder of granules fills up).

    Raises
    ------
    InputError
        Naming both folders.
    """
    o = out.resolve()
    for item in inputs:
        folder = Path(item)
        if not folder.is_dir():
            continue
        f = folder.resolve()
        if o == f or f in o.parents:
            where = "is" if o == f else "lies inside"
            raise InputError(
                f"the output folder {out} {where} the input folder {folder}: a batch writes "
                "rasters, partitions and a manifest there and would read them back as "
                "inputs; choose an output folder outside the inputs")


def _is_partial(p: Path) -> bool:
    return p.name.startswith(".") and ".part" in p.name


def remove_partial_outputs(out: Path) -> list[Path]:
    """Remove the partial files (and folders) of atomic writes under ``out``; return them."""
    if not out.is_dir():
        return []
    gone = [p for p in out.rglob(".*") if _is_partial(p)]
    for p in sorted(gone, key=lambda q: len(q.parts), reverse=True):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
        log.info("removed the partial output %s", p)
    return gone


def complete_outputs(out: Path) -> set[Path]:
    """Every complete file under ``out`` (partial files excluded)."""
    if not out.is_dir():
        return set()
    return {p for p in out.rglob("*") if p.is_file() and not any(
        _is_partial(Path(part)) for part in p.relative_to(out).parts)}


@contextlib.contextmanager
def private_tempdir() -> Iterator[str]:
    """A temporary folder for the workers of one batch, removed when the block ends
    (after the workers: whatever a killed worker left there goes with it)."""
    path = tempfile.mkdtemp(prefix="canopyblocks-batch-")
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
