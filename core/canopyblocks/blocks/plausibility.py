"""Blocks whose canopy height no tree can have are flagged, not reported as canopy.

A daytime ICESat-2 granule read without a signal filter is mostly solar background: the
block engine then finds a "canopy top" in the noise, hundreds of metres above the ground.
Those blocks keep their values (a profile can show them) but are flagged ``implausible``
and excluded from validation like ``sparse`` and ``inverted`` blocks, with one warning per
call that says why and what to do.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from ..errors import CanopyBlocksWarning
from ..schema import FLAG_IMPLAUSIBLE, FLAG_OK, MAX_CANOPY_HEIGHT_M

__all__ = ["MAX_CANOPY_HEIGHT_M", "ImplausibleBlockWarning", "background_fraction",
           "flag_implausible_blocks"]



class ImplausibleBlockWarning(CanopyBlocksWarning):
    """Some blocks had an Hmax taller than any tree and were flagged ``implausible``."""


def flag_implausible_blocks(blocks: pd.DataFrame, track: str,
                            background: float | None = None) -> pd.DataFrame:
    """Flag ``ok`` blocks with ``hmax`` above :data:`MAX_CANOPY_HEIGHT_M` (in place).

    Parameters
    ----------
    blocks : DataFrame
        Block table with ``hmax`` (m) and ``flag`` columns.
    track : str
        Named in the warning.
    background : float, optional
        Fraction of the track's photons the product marks as background (ATL03
        ``signal_conf_ph`` 0), quoted in the warning when given.

    Returns
    -------
    DataFrame
        ``blocks`` itself.
    """
    hmax = blocks["hmax"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        bad = (blocks["flag"].to_numpy() == FLAG_OK) & (hmax > MAX_CANOPY_HEIGHT_M)
    if not bad.any():
        return blocks
    blocks.loc[bad, "flag"] = FLAG_IMPLAUSIBLE
    noise = (f"; {background:.0%} of its photons are background noise (signal_conf 0)"
             if background is not None else "")
    warnings.warn(
        f"track {track}: {int(bad.sum())} of {len(blocks)} blocks have Hmax above "
        f"{MAX_CANOPY_HEIGHT_M:g} m (up to {np.nanmax(hmax[bad]):.0f} m), taller than any tree; "
        f"they are flagged '{FLAG_IMPLAUSIBLE}'{noise}. Most likely the background photons "
        "were kept: use the recommended atl08 estimators (the default, --preset atl08), "
        "which class the background"
        + ("" if background is None else ", or filter by signal confidence "
           "(--min-signal-conf 2 with --preset paper or icesat2)"),
        ImplausibleBlockWarning, stacklevel=3)
    return blocks


def background_fraction(signal_conf: np.ndarray | None) -> float | None:
    """Fraction of photons with ATL03 land confidence 0 (noise); None without confidences."""
    if signal_conf is None or np.size(signal_conf) == 0:
        return None
    return float(np.count_nonzero(np.asarray(signal_conf) == 0) / np.size(signal_conf))
