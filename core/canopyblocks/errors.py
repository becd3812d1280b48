"""Exceptions and warnings of canopyblocks.

Every error the package raises on purpose derives from :class:`CanopyBlocksError`
and also from the builtin exception a caller would expect (an input error is a
``ValueError``, a file error an ``OSError``), so ``except ValueError`` keeps
working.  Messages say what was received, what is allowed, and what to do.
"""

from __future__ import annotations

__all__ = [
    "CanopyBlocksError",
    "InputError",
    "FileFormatError",
    "NoUsableDataError",
    "CRSError",
    "DatumError",
    "CoverageError",
    "DependencyError",
    "PdalError",
    "CancelledError",
    "CanopyBlocksWarning",
    "SparseBlockWarning",
    "CanopyBlocksDeprecationWarning",
    "warn_renamed",
]


class CanopyBlocksError(Exception):
    """Root of every error raised on purpose by canopyblocks."""


class InputError(CanopyBlocksError, ValueError):
    """A parameter, argument or input value is not acceptable."""


class FileFormatError(CanopyBlocksError, OSError):
    """A file is missing, unreadable, truncated, or lacks a required group/dataset.

    The message names the file and what is missing.
    """


class NoUsableDataError(InputError):
    """The input is readable but holds nothing the requested processing can use."""


class CRSError(InputError):
    """A coordinate reference system is missing, not metric, or inconsistent."""


class DatumError(InputError):
    """Heights in different vertical datums would be mixed without a conversion."""


class CoverageError(InputError):
    """Reference data (rasters, tiles) do not cover the track."""


class DependencyError(CanopyBlocksError, ImportError):
    """An optional dependency or external program (e.g. the ``pdal`` command) is missing."""


class PdalError(CanopyBlocksError, RuntimeError):
    """A PDAL pipeline run in a subprocess failed; the message carries PDAL's own error."""


class CancelledError(CanopyBlocksError):
    """The user cancelled a long-running operation; no output file was left behind."""


class CanopyBlocksWarning(UserWarning):
    """Base class of canopyblocks warnings."""


class SparseBlockWarning(CanopyBlocksWarning):
    """Some blocks held too few photons to compute metrics; they are flagged ``sparse``."""


class CanopyBlocksDeprecationWarning(CanopyBlocksWarning, FutureWarning):
    """An old spelling (keyword, option, value) that still works for a release; the message
    names the new one."""


def warn_renamed(old: str, new: str, stacklevel: int = 3) -> None:
    """The one warning for a renamed keyword: ``old`` still works, use ``new``."""
    import warnings

    warnings.warn(f"{old} is deprecated and will be removed; use {new}",
                  CanopyBlocksDeprecationWarning, stacklevel=stacklevel)
