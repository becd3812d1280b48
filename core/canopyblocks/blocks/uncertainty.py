"""Per-block uncertainty of the ATL08-style heights: ``hmax_sigma`` and ``ground_sigma``.

A block's (or segment's) 1-sigma error, metres, predicted from what the block holds
(DESIGN 1.12):

- its photons by class (ground, canopy, top of canopy) and the noise photons in it,
- the background density the classifier used (photons per metre along-track per metre
  of height: the ATL03 ``bckgrd_rate``, or estimated from the photons),
- the signal photons per metre of track (a strong beam holds ~4x a weak one),
- the terrain slope over the block (the classifier's ground surface),
- the block length,
- the classifier's own surface fit: the spread of the ground photons about the surface,
- the block's Hmax itself.

Three parts, added in quadrature (m):

- the measurement: a log-linear ``log s = x . beta`` on the quantities above, times a
  tail factor per regime (strong or weak beam, night or day), chosen so that 1 and 2 sigma
  both cover as stated: the residuals' shape is not a Gaussian's and differs by regime
  (a weak beam by day has the heaviest tails);
- the geolocation, ground: ``G x slope``, where ``G`` is the horizontal geolocation
  1-sigma (m): the file's own ``geolocation/sigma_along`` and ``sigma_across`` (ATL03,
  per 20 m segment), ``G = sqrt(sigma_along^2 + sigma_across^2)``, else ICESat-2's
  published figure (:data:`PUBLISHED_GEOLOCATION_SIGMA`); the block's along-track slope
  stands for the across-track one, which one track cannot see;
- the geolocation, Hmax: ``k x G x canopy gradient`` (the RMS slope of the canopy-top
  profile in 5 m steps along the block; ``k`` fitted).

``beta``, ``k`` and the tail factors are fitted on residuals against the
footprint-matched reference (like with like, DESIGN 2.7) of simulated tracks over the
**calibration tiles only**, reported 0, 3 and 6 m off their true place
(``bench/fit_block_sigma.py``); they are stored in ``uncertainty_model.json`` beside this
module. Blocks whose ``hmax_sigma`` or
``ground_sigma`` exceed the model's thresholds are flagged ``low_confidence``; every block
carries ``use`` (False = left out of headline statistics: not ``ok``).

Only the ``atl08`` preset's blocks (and ATL08-style segments) get a sigma: the other
estimators' errors are not modelled (NaN; their ``use`` follows their flag alone).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..schema import FLAG_LOW_CONFIDENCE, FLAG_OK
from .uncertainty_features import block_features

if TYPE_CHECKING:
    import pandas as pd

    from ..photons import PhotonTrack
    from .atl08_classify import Atl08Classes

__all__ = ["SigmaModel", "FEATURES", "PUBLISHED_GEOLOCATION_SIGMA", "REGIMES",
           "geolocation_sigma", "regime_of", "FLAG_LOW_CONFIDENCE", "sigma_model", "block_features",
           "design_matrix", "predict_sigma", "add_block_sigma", "add_segment_sigma",
           "mark_use", "upgrade_table", "left_out_summary"]

#: Terms of the log-linear model, in the order of the coefficients.
FEATURES: tuple[str, ...] = (
    "const",
    "log_n_top",       # log(1 + top-of-canopy photons)
    "log_n_canopy",    # log(1 + canopy photons, classes 2-3)
    "log_n_ground",    # log(1 + ground photons)
    "log_signal_per_m",  # log(signal photons per metre of track + 0.05): beam strength
    "log_background",  # log(background photons per m along per m height x block length + 0.01)
    "log_noise_frac",  # log((noise photons in block + 1) / (all photons + 1))
    "log_noise_top",   # log(1 + noise photons 0-10 m above the block's Hmax)
    "log_noise_ground",  # log(1 + noise photons within 3 m of the ground surface)
    "log_slope",       # log(0.02 + |rise| of the ground surface over the block / length)
    "log_ground_spread",  # log(0.05 + sd of ground photons about the surface, m)
    "log_ground_offset",  # log(0.05 + |mean height of the ground photons above the surface|)
    "log_relief",      # log(0.05 + |z(c-15) + z(c+15) - 2 z(c)| of the surface, m)
    "log_length",      # log(block length / 25 m)
    "log_hmax",        # log(1 + Hmax, m)
)

_MODEL_FILE = Path(__file__).with_name("uncertainty_model.json")

#: ICESat-2's horizontal geolocation 1-sigma, m (radial): the worst beam's remaining
#: error after calibration, mean + 1 sigma (Luthcke et al. 2021, Earth and Space Science
#: 8, e2020EA001494: 2.5 m for beam 6 to 4.4 m for beam 2). Used where the file states none.
PUBLISHED_GEOLOCATION_SIGMA = 4.4

#: Regimes with their own tail factor: (beam, light).
REGIMES: tuple[str, ...] = ("strong night", "strong day", "weak night", "weak day")


@dataclass(frozen=True)
class SigmaModel:
    """Fitted coefficients of the sigma model (see the module notes).

    Attributes
    ----------
    hmax : tuple of float
        Coefficients of ``log hmax_sigma`` on :data:`FEATURES`.
    ground : tuple of float
        Coefficients of ``log ground_sigma``.
    hmax_max : float
        ``hmax_sigma`` above this (m) flags a block ``low_confidence``.
    ground_max : float
        ``ground_sigma`` above this (m) flags a block ``low_confidence``.
    floor : float
        Smallest sigma given, m.
    fitted_on : str
        What the model was fitted on.
    hmax_tail, ground_tail : tuple of float
        Tail factor on the measurement part per :data:`REGIMES`.
    hmax_geo : float
        ``k``: Hmax's geolocation term per metre of geolocation and unit canopy gradient.
    weak_signal : float
        Signal photons per metre of track under which a block counts as a weak beam's.
    day_background : float
        Background photons per m along-track per m of height over which it is daylight.
    """

    hmax: tuple[float, ...]
    ground: tuple[float, ...]
    hmax_max: float
    ground_max: float
    floor: float = 0.1
    fitted_on: str = ""
    hmax_tail: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    ground_tail: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    hmax_geo: float = 1.0
    weak_signal: float = 1.0
    day_background: float = 0.0048

    def __post_init__(self) -> None:
        vectors = (("hmax", len(FEATURES), "finite coefficients", np.isfinite),
                   ("ground", len(FEATURES), "finite coefficients", np.isfinite),
                   ("hmax_tail", len(REGIMES), "positive factors", lambda a: a > 0),
                   ("ground_tail", len(REGIMES), "positive factors", lambda a: a > 0))
        for name, size, what, good in vectors:
            v = getattr(self, name)
            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                arr = np.array([np.nan])
            if arr.shape != (size,) or not np.all(good(arr)):
                raise InputError(f"sigma model: {name} needs {size} {what}, got {v!r}")
        for name in ("hmax_max", "ground_max", "floor", "weak_signal", "day_background"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise InputError(f"sigma model: {name} must be a positive number, "
                                 f"got {v!r}")
        if not (isinstance(self.hmax_geo, (int, float)) and self.hmax_geo >= 0):
            raise InputError(f"sigma model: hmax_geo must be >= 0, got {self.hmax_geo!r}")

    def to_json(self) -> str:
        """The model as JSON (the package file's format)."""
        return json.dumps({"features": list(FEATURES), "hmax": list(self.hmax),
                           "ground": list(self.ground), "hmax_max": self.hmax_max,
                           "ground_max": self.ground_max, "floor": self.floor,
                           "hmax_tail": list(self.hmax_tail),
                           "ground_tail": list(self.ground_tail), "hmax_geo": self.hmax_geo,
                           "weak_signal": self.weak_signal,
                           "day_background": self.day_background,
                           "fitted_on": self.fitted_on}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> SigmaModel:
        """Read :meth:`to_json`'s format."""
        d = json.loads(text)
        if tuple(d.get("features", ())) != FEATURES:
            raise InputError("sigma model: its features are not this version's; refit it")
        if "hmax_tail" not in d:
            raise InputError("sigma model: it has no geolocation or tail terms (an older "
                             "version's); refit it")
        return cls(tuple(map(float, d["hmax"])), tuple(map(float, d["ground"])),
                   float(d["hmax_max"]), float(d["ground_max"]), float(d.get("floor", 0.1)),
                   str(d.get("fitted_on", "")), tuple(map(float, d["hmax_tail"])),
                   tuple(map(float, d["ground_tail"])), float(d["hmax_geo"]),
                   float(d["weak_signal"]), float(d["day_background"]))


@lru_cache(maxsize=1)
def sigma_model() -> SigmaModel:
    """The package's fitted model (``uncertainty_model.json``)."""
    return SigmaModel.from_json(_MODEL_FILE.read_text())


def geolocation_sigma(f: dict[str, np.ndarray] | pd.DataFrame, model: SigmaModel | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The geolocation parts of ``hmax_sigma, ground_sigma`` (1 sigma, m) of each interval.

    Ground: ``G x slope``; Hmax: ``k x G x canopy_gradient``, where ``G`` is ``geo_sigma``
    (the file's horizontal geolocation 1-sigma, m) or, where NaN or absent,
    :data:`PUBLISHED_GEOLOCATION_SIGMA`, and ``slope`` the along-track slope of the ground
    surface over the block (m/m; it stands for the unseen across-track slope too).
    """
    m = sigma_model() if model is None else model
    slope = np.minimum(np.asarray(f["slope"], float), 1.0)
    geo = np.asarray(f["geo_sigma"], float) if "geo_sigma" in f else np.full(slope.shape,
                                                                              np.nan)
    geo = np.where(np.isfinite(geo) & (geo > 0), geo, PUBLISHED_GEOLOCATION_SIGMA)
    grad = np.asarray(f["canopy_gradient"], float) if "canopy_gradient" in f else 0 * slope
    grad = np.where(np.isfinite(grad), grad, 0.0)
    return m.hmax_geo * geo * grad, geo * np.where(np.isfinite(slope), slope, 0.0)


def regime_of(f: dict[str, np.ndarray] | pd.DataFrame, model: SigmaModel | None = None
              ) -> np.ndarray:
    """Index into :data:`REGIMES` of each interval: weak when its signal photons per metre
    are under ``model.weak_signal``, day when its background is over ``day_background``."""
    m = sigma_model() if model is None else model
    length = np.asarray(f["length"], float)
    n_sig = np.asarray(f["n_ground"], float) + np.asarray(f["n_canopy"], float)
    weak = n_sig / length < m.weak_signal
    day = np.asarray(f["background"], float) > m.day_background
    return 2 * weak.astype(np.int64) + day.astype(np.int64)


def design_matrix(f: dict[str, np.ndarray] | pd.DataFrame) -> np.ndarray:
    """The model's terms (:data:`FEATURES`) from :func:`block_features`' quantities."""
    length = np.asarray(f["length"], float)
    n_sig = np.asarray(f["n_ground"], float) + np.asarray(f["n_canopy"], float)
    spread = np.asarray(f["ground_spread"], float)
    spread = np.where(np.isfinite(spread), np.minimum(spread, 5.0), 1.0)
    offset = np.abs(np.asarray(f["ground_offset"], float))
    offset = np.where(np.isfinite(offset), np.minimum(offset, 5.0), 1.0)
    hmax = np.asarray(f["hmax"], float)
    hmax = np.where(np.isfinite(hmax), np.clip(hmax, 0.0, 80.0), 0.0)
    cols = [np.ones_like(length),
            np.log1p(np.asarray(f["n_top"], float)),
            np.log1p(np.asarray(f["n_canopy"], float)),
            np.log1p(np.asarray(f["n_ground"], float)),
            np.log(n_sig / length + 0.05),
            np.log(np.asarray(f["background"], float) * length + 0.01),
            np.log((np.asarray(f["n_noise"], float) + 1) / (np.asarray(f["n_all"], float) + 1)),
            np.log1p(np.asarray(f["n_noise_top"], float)),
            np.log1p(np.asarray(f["n_noise_ground"], float)),
            np.log(np.minimum(np.asarray(f["slope"], float), 1.0) + 0.02),
            np.log(0.05 + spread),
            np.log(0.05 + offset),
            np.log(0.05 + np.minimum(np.asarray(f["relief"], float), 20.0)),
            np.log(length / 25.0),
            np.log1p(hmax)]
    return np.column_stack(cols)


def predict_sigma(f: dict[str, np.ndarray] | pd.DataFrame, model: SigmaModel | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``hmax_sigma, ground_sigma`` (1 sigma, m) of each interval; NaN where no Hmax: the
    measurement part (log-linear, times the regime's tail factor) and the geolocation part
    (:func:`geolocation_sigma`) in quadrature."""
    m = sigma_model() if model is None else model
    x = design_matrix(f)
    reg = regime_of(f, m)
    gh, gg = geolocation_sigma(f, m)
    with np.errstate(over="ignore"):
        hs = np.exp(np.clip(x @ np.asarray(m.hmax), -10, 10)) * np.asarray(m.hmax_tail)[reg]
        gs = np.exp(np.clip(x @ np.asarray(m.ground), -10, 10)) * np.asarray(m.ground_tail)[reg]
    hs = np.maximum(np.hypot(hs, gh), m.floor)
    gs = np.maximum(np.hypot(gs, gg), m.floor)
    none = ~np.isfinite(np.asarray(f["hmax"], float))
    hs[none] = np.nan
    gs[none] = np.nan
    return hs, gs


def mark_use(table: pd.DataFrame, model: SigmaModel | None = None) -> pd.DataFrame:
    """Flag ``low_confidence`` where a sigma is over the model's threshold (``ok`` blocks
    only) and set ``use`` = flag is ``ok``; in place, and returned."""
    m = sigma_model() if model is None else model
    flag = table["flag"].astype(object).to_numpy()
    hs = table["hmax_sigma"].to_numpy(float)
    gs = table["ground_sigma"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        wide = (hs > m.hmax_max) | (gs > m.ground_max)
    flag = np.where((flag == FLAG_OK) & wide, FLAG_LOW_CONFIDENCE, flag)
    table["flag"] = flag
    table["use"] = flag == FLAG_OK
    return table


def upgrade_table(table: pd.DataFrame) -> pd.DataFrame:
    """A block, segment, footprint or residuals table read from a file, in today's form; in
    place, and returned. The one place older tables are upgraded (the readers call it):

    - ``hmax_sigma``/``ground_sigma`` missing (written before the error bars): NaN;
    - ``use`` missing (written before it): the rows :func:`mark_use` would use, flag ``ok``
      (and, in a residuals table, a usable reference: ``ref_flag`` ``ok``);
    - ``use`` stored as 0/1 or NULL (a GeoPackage or QGIS layer): a bool, NULL False.

    A table without a ``flag`` column (statistics, pixels) is returned unchanged.
    """
    if "flag" not in table.columns:
        return table
    if "hmax" in table.columns:  # blocks and block residuals carry error bars
        for c in ("hmax_sigma", "ground_sigma"):
            if c not in table.columns:
                table[c] = np.nan
    if "use" in table.columns:
        table["use"] = table["use"].fillna(False).astype(bool).to_numpy()
    else:
        use = table["flag"].astype(object).to_numpy() == FLAG_OK
        if "ref_flag" in table.columns:
            use &= table["ref_flag"].astype(object).to_numpy() == FLAG_OK
        table["use"] = use
    return table


def add_block_sigma(blocks: pd.DataFrame, track: PhotonTrack, classes: Atl08Classes,
                    model: SigmaModel | None = None) -> pd.DataFrame:
    """Fill ``hmax_sigma``, ``ground_sigma``, the ``low_confidence`` flag and ``use`` of an
    ``atl08`` block table (every length), in place; returned."""
    hs = np.full(len(blocks), np.nan)
    gs = np.full(len(blocks), np.nan)
    lengths = blocks["length"].to_numpy(float)
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        sub = blocks.iloc[rows]
        order = np.argsort(sub["s_start"].to_numpy(float), kind="stable")
        r = rows[order]
        f = block_features(track, classes, blocks["s_start"].to_numpy(float)[r],
                           blocks["s_end"].to_numpy(float)[r],
                           blocks["hmax"].to_numpy(float)[r])
        hs[r], gs[r] = predict_sigma(f, model)
    blocks["hmax_sigma"] = hs
    blocks["ground_sigma"] = gs
    return mark_use(blocks, model)


def add_segment_sigma(segments: pd.DataFrame, track: PhotonTrack, classes: Atl08Classes,
                      model: SigmaModel | None = None) -> pd.DataFrame:
    """``hmax_sigma`` (of ``h_canopy``), ``ground_sigma`` (of the mean ground surface),
    the ``low_confidence`` flag and ``use`` of ATL08-style segments, in place; returned.
    Segments with no canopy photon take the sigma of a bare block (Hmax 0); ``use`` is
    True only for ``ok`` segments (:func:`mark_use`)."""
    m = sigma_model() if model is None else model
    order = np.argsort(segments["s_start"].to_numpy(float), kind="stable")
    h = segments["h_canopy"].to_numpy(float)[order]
    f = block_features(track, classes, segments["s_start"].to_numpy(float)[order],
                       segments["s_end"].to_numpy(float)[order], np.where(np.isfinite(h), h, 0))
    hs, gs = np.full(len(segments), np.nan), np.full(len(segments), np.nan)
    hs[order], gs[order] = predict_sigma(f, m)
    segments["hmax_sigma"] = hs
    segments["ground_sigma"] = gs
    return mark_use(segments, m)


def left_out_summary(table: pd.DataFrame) -> dict[str, object]:
    """How many rows headline statistics leave out and why.

    Returns
    -------
    dict
        ``n`` (rows), ``n_used``, ``n_left_out``, ``by_flag`` (left-out rows per reason:
        the block's flag, or ``reference <ref_flag>`` in a residuals table),
        ``n_low_confidence``, ``hmax_sigma_max`` and ``ground_sigma_max`` (the thresholds,
        m) -- for a report's sentence.
    """
    import pandas as pd

    from ..arguments import check_frame
    check_frame(table, "left_out_summary: table", "a block, segment or residuals table")
    m = sigma_model()
    n = len(table)
    use = upgrade_table(table.copy())["use"].to_numpy(bool) if "flag" in table.columns \
        else (table["use"].fillna(False).to_numpy(bool) if "use" in table.columns
              else np.ones(n, bool))
    why = (table["flag"].astype(str).to_numpy(object) if "flag" in table.columns
           else np.full(n, "not used", object))
    if "ref_flag" in table.columns:  # a residuals table: the reference's reason too
        rf = table["ref_flag"].astype(str).to_numpy(object)
        why = np.where((why == FLAG_OK) & (rf != FLAG_OK), "reference " + rf, why)
    left = pd.Series(why[~use])
    by_flag = {str(k): int(v) for k, v in left.value_counts().items()}
    return {"n": n, "n_used": int(use.sum()), "n_left_out": int(n - use.sum()),
            "by_flag": by_flag, "n_low_confidence": by_flag.get(FLAG_LOW_CONFIDENCE, 0),
            "hmax_sigma_max": m.hmax_max, "ground_sigma_max": m.ground_max}
