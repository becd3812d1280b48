"""Flash focal-plane-array data cubes (seed 003, DESIGN 4.7): footprints from pixels.

An ESFL cube images each footprint on a subset of pixels (12 x 12 in seed 003); every
pixel records its own waveform. Seed 003 defines a footprint's extent from the flight
line's *average* cube, over the 4 x 4 pixel region centred on the footprint's location
(the centre of its subset): per pixel the time-summed energy averaged over all cubes,
divided by the brightest pixel of the region; pixels at or above a fraction ``f`` of it
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


def footprint_mask(cubes: np.ndarray, fraction: float = 0.5, region: int | None = 4
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of the central ``region`` x ``region`` pixels whose average time-summed
    energy is >= ``fraction`` of the brightest's there.

    Parameters
    ----------
    cubes : ndarray (footprints, rows, cols, bins)
        Pixel waveforms of every footprint of one flight line (noise included).
    fraction : float
        In (0, 1].
    region : int or None
        Side (pixels) of the square region centred on the subset's centre that can
        belong to the footprint (4 in the flash-lidar paper); None: the whole subset.

    Returns
    -------
    mask : ndarray bool (rows, cols)
    ratio : ndarray (rows, cols)
        Average energy over the region's brightest pixel's (0 outside the region).
    """
    c = np.asarray(cubes, float)
    if c.ndim != 4:
        raise InputError(f"cubes must have shape (footprints, rows, cols, bins); got {c.shape}")
    if not (0.0 < fraction <= 1.0):
        raise InputError(f"energy fraction must be in (0, 1] (seed 003 tested 0.1-0.9); "
                         f"got {fraction!r}")
    rows, cols = c.shape[1:3]
    inside = np.ones((rows, cols), bool)
    if region is not None:
        if isinstance(region, bool) or not isinstance(region, (int, np.integer)) \
                or not (1 <= region <= min(rows, cols)):
            raise InputError(f"region must be an integer 1..{min(rows, cols)} pixels (the "
                             f"subset's side); got {region!r}")
        r0, c0 = (rows - region) // 2, (cols - region) // 2
        inside[:] = False
        inside[r0:r0 + region, c0:c0 + region] = True
    energy = c.sum(axis=3).mean(axis=0)  # the flight line's average image
    energy = np.where(inside, energy, 0.0)
    peak = float(energy.max())
    if not peak > 0:
        raise InputError("the cubes hold no positive energy; nothing to aggregate")
    ratio = energy / peak
    return inside & (ratio >= fraction - 1e-12), ratio


def aggregate_footprints(cubes: np.ndarray, fraction: float = 0.5, region: int | None = 4
                         ) -> FlashFootprints:
    """Footprint waveforms: the mean over the footprint's pixels (seed 003)."""
    mask, ratio = footprint_mask(cubes, fraction, region)
    c = np.asarray(cubes, float)
    wf = c[:, mask, :].mean(axis=1)
    return FlashFootprints(wf, mask, int(mask.sum()), ratio)
