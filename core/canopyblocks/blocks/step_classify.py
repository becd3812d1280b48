"""Seed 002's classification of simulated photons into ground and top of canopy.

Along the track, in steps of ``step`` photons (20 in the seed), with ``min20``/``max20``
the lowest/highest photon height of the step:

* ground photons: ``h < min20 + 3 * PSF``;
* top-of-canopy photons: ``h > max20 - 1 m`` (the seed prints ``photon < abs(max20 - 1)``,
  a typesetting slip; its text says "within 1 m of the sample bin maximum").

The two sets are computed independently, as in the seed (on bare ground a photon can
be in both).  Steps never span two realisations; the last step of a realisation may
hold fewer photons.  Photons must be ordered along the track within each realisation.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["classify_seed002", "seed002_labels"]


def classify_seed002(h: np.ndarray, group: np.ndarray | None = None, *, psf: float = 0.25,
                     step: int = 20, top_window: float = 1.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground and top-of-canopy masks of photons (seed 002, section 2.2).

    Parameters
    ----------
    h : ndarray
        Photon heights, metres, in along-track order (within each group).
    group : ndarray of int, optional
        Realisation (or track) id per photon, non-decreasing; steps restart at each
        new group.  None = one group.
    psf : float
        Point-spread sigma, metres (ground window = 3 PSF above the step minimum).
    step : int
        Photons per step (20).
    top_window : float
        Top-of-canopy window below the step maximum, metres (1 m).

    Returns
    -------
    ground, top : ndarray bool
        Masks of ground and top-of-canopy photons.
    step_id : ndarray int64
        Step index of each photon (global over groups).
    """
    h = np.asarray(h, dtype=np.float64)
    n = h.size
    if step < 1:
        raise InputError(f"step must be >= 1 photon; got {step}")
    if n == 0:
        e = np.zeros(0, bool)
        return e, e.copy(), np.zeros(0, np.int64)
    if group is None:
        pos = np.arange(n, dtype=np.int64)
        new_group = np.zeros(n, bool)
        new_group[0] = True
    else:
        g = np.asarray(group)
        if g.size != n:
            raise InputError(f"group has {g.size} values for {n} photons")
        if np.any(np.diff(g) < 0):
            raise InputError("photons must be sorted by group (realisation) first")
        new_group = np.concatenate([[True], g[1:] != g[:-1]])
        gstart = np.maximum.accumulate(np.where(new_group, np.arange(n), 0))
        pos = np.arange(n, dtype=np.int64) - gstart
    new_step = new_group | (pos % step == 0)
    step_id = np.cumsum(new_step) - 1
    starts = np.flatnonzero(new_step)
    lo = np.minimum.reduceat(h, starts)[step_id]
    hi = np.maximum.reduceat(h, starts)[step_id]
    ground = h < lo + 3.0 * psf
    top = h > hi - top_window
    return ground, top, step_id


def seed002_labels(ground: np.ndarray, top: np.ndarray) -> np.ndarray:
    """ATL08-style labels: 1 ground, 3 top of canopy, 2 other canopy (ground wins ties)."""
    lab = np.full(ground.size, 2, dtype=np.int8)
    lab[top] = 3
    lab[ground] = 1
    return lab
