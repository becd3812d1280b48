"""Flash focal-plane-array data cubes (seed 003, DESIGN 4.7): footprints from pixels.

An ESFL cube images each footprint on a subset of pixels (12 x 12 in seed 003); every
pixel records its own waveform. Seed 003 defines a footprint's extent from the flight
line's *average* cube: per pixel the time-summed energy averaged over all cubes, divided
by the brightest pixel of the footprint; pixels at or above a fraction ``f`` of it
(default 0.5; the paper tested 0.1-0.9 and found 0.5 best) belong to the footprint, and
the footprint waveform is the mean of those pixels' waveforms.

Arrays: ``cubes`` has shape (footprints, rows, cols, bins); bin 0 is the highest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["FlashFootprints", "footprint_mask", "aggregate_footprints"]


@dataclass(frozen=True)
class FlashFootprints:
    """Aggregated footprints: ``waveforms`` (footprints, bins), the pixel ``mask``
    (rows, cols) shared by every footprint of the flight line, ``n_pixels`` in it, and
    the average ``energy_ratio`` image (rows, cols) the mask came from."""

    waveforms: np.ndarray
    mask: np.ndarray
    n_pixels: int
    energy_ratio: np.ndarray


def footprint_mask(cubes: np.ndarray, fraction: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Pixels whose average time-summed energy is >= ``fraction`` of the brightest's.

    Parameters
    ----------
    cubes : ndarray (footprints, rows, cols, bins)
        Pixel waveforms of every footprint of one flight line (noise included).
    fraction : float
        In (0, 1].

    Returns
    -------
    mask : ndarray bool (rows, cols)
    ratio : ndarray (rows, cols)
        Average energy over the brightest pixel's.
    """
    c = np.asarray(cubes, float)
    if c.ndim != 4:
        raise InputError(f"cubes must have shape (footprints, rows, cols, bins); got {c.shape}")
    if not (0.0 < fraction <= 1.0):
        raise InputError(f"energy fraction must be in (0, 1] (seed 003 tested 0.1-0.9); "
                         f"got {fraction!r}")
    energy = c.sum(axis=3).mean(axis=0)  # the flight line's average image
    peak = float(energy.max())
    if not peak > 0:
        raise InputError("the cubes hold no positive energy; nothing to aggregate")
    ratio = energy / peak
    return ratio >= fraction - 1e-12, ratio


def aggregate_footprints(cubes: np.ndarray, fraction: float = 0.5) -> FlashFootprints:
    """Footprint waveforms: the mean over the footprint's pixels (seed 003)."""
    mask, ratio = footprint_mask(cubes, fraction)
    c = np.asarray(cubes, float)
    wf = c[:, mask, :].mean(axis=1)
    return FlashFootprints(wf, mask, int(mask.sum()), ratio)
