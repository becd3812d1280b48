"""Compiled loops of the ATL08-style classifier, with numpy as the fallback (the same bits).

Some of the classifier's loops run along the track in one pass (the surface passes'
weights and binned sums, the density filter's box counts); numpy does them in many passes
over full-length temporaries. Where numba is installed (the ``all`` extra) they run as
single-pass compiled loops, cached on disk so only the first run on a machine compiles
(about a few seconds). Where it is missing, or ``CANOPYBLOCKS_NUMBA=0`` is set, the numpy
code runs instead; both give identical results (tested against each other).

The compile cache goes beside this module when that folder is writable, else into the
user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``, ``canopyblocks/numba``), else a
temporary folder; ``NUMBA_CACHE_DIR``, when set, wins.
"""

from __future__ import annotations

import importlib
import os
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

__all__ = ["enabled", "compiled"]

_STATE: dict[str, Any] = {}


def enabled() -> bool:
    """Whether the compiled loops are used: numba imports and ``CANOPYBLOCKS_NUMBA`` is
    not ``0`` (read on each call, so tests can switch)."""
    if os.environ.get("CANOPYBLOCKS_NUMBA", "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    return compiled() is not None


def _cache_dir() -> None:
    """Point numba's cache at a writable folder when the package's own is not."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = Path(__file__).resolve().parent
    if os.access(here, os.W_OK):
        return  # numba caches in __pycache__ beside this module
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    for d in (base / "canopyblocks" / "numba",
              Path(tempfile.gettempdir()) / f"canopyblocks-numba-{os.getuid()}"):
        try:
            d.mkdir(parents=True, exist_ok=True)
            own = d.stat().st_uid == os.getuid()
        except OSError:
            continue
        # numba loads pickled files from its cache: only a folder of this user's own
        if own and os.access(d, os.W_OK):
            os.environ["NUMBA_CACHE_DIR"] = str(d)
            return


def compiled() -> ModuleType | None:
    """The compiled kernels' module (imported once, lazily: numba costs ~0.3 s to import),
    or None where numba is missing."""
    if "mod" not in _STATE:
        mod: ModuleType | None
        try:
            _cache_dir()
            mod = importlib.import_module(__name__ + "_numba")
        except (ImportError, RuntimeError, OSError):
            # numba missing, or no folder to cache its compiled code in ("cannot cache
            # function"): the numpy code gives the same bits
            mod = None
        _STATE["mod"] = mod
    return _STATE["mod"]
