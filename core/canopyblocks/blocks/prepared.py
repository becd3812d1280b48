"""The engine's working types: the photons of a track prepared for blocking
(:class:`PreparedTrack`) and the blocks of one length (:class:`LengthResult`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    pass

@dataclass
class PreparedTrack:
    """The photons the engine uses, sorted by ``s``, with ``s >= s0`` and finite values.

    ``index`` maps them back to the track's photon positions (None: they are the
    track's photons ``first:`` in order, ``first`` given).
    """

    s: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray
    conf_mask: np.ndarray | None
    s0: float
    index: np.ndarray | None
    first: int
    n_track: int


@dataclass
class LengthResult:
    """Engine output for one block length (arrays per block with >= 1 photon)."""

    length: float
    block: np.ndarray
    n_photons: np.ndarray
    n_kept: np.ndarray
    n_between: np.ndarray
    top: np.ndarray
    ground: np.ndarray
    z90: np.ndarray
    flag: np.ndarray          # codes into ("ok", "sparse", "inverted")
    x: np.ndarray
    y: np.ndarray
    labels: np.ndarray | None  # per prepared photon
