"""Block estimators beyond the paper (DESIGN 1.10): named options and presets.

The default is the ATL08-style classifier (the preset ``atl08``, :data:`RECOMMENDED_PRESET`):
``Estimators()``, ``preset()`` and every function taking ``estimators=None`` use it. The
paper's method (DESIGN 1.1-1.8) stays, bit for bit, as the preset ``paper``. These options
name the parts of a block's computation (a custom set names all three):

- ``noise``: ``sigma`` (the paper's per-block 2.5-sigma filter), ``conf`` (ATL03
  ``signal_conf_ph >= min_signal_conf``), ``density`` (DRAGANN-like,
  :mod:`.density_filter`, for data without a confidence flag), ``atl08`` (the ATL08-style
  classifier, :mod:`.atl08_classify`: photons classed noise are removed), ``none``;
- ``ground``: ``paper`` (upper edge of the expansion window), ``surface`` (mean of a
  robust along-track ground surface over the block, :mod:`.ground_surface`) or ``atl08``
  (mean of the ATL08-style classifier's ground surface; needs ``noise="atl08"``);
- ``top``: ``paper`` (lower edge of the top window), ``p95``/``p98``/``p99``/``p100``
  (percentile of the kept photons' heights in the block, numpy's linear interpolation;
  p100 = the highest kept photon) or ``atl08`` (98th percentile of the canopy photons'
  heights above the ground surface, :mod:`.atl08_blocks`; needs ``ground="atl08"``).

``hmax = top - ground``; ``z90`` is the paper's 90th percentile (index
``floor(0.9 (n - 1))``) of the kept photons with ``ground <= z <= top``; ``h90 = z90 -
ground``. Flags as in the paper: ``sparse`` (fewer than ``min_photons`` kept),
``inverted`` (top <= ground or nothing between).

Presets name combinations (:data:`PRESETS`): ``paper``; ``icesat2`` (density filter, the
paper's ground window, p98 top: measured best on unseen tiles with night and day background
noise -- bench/bench_icesat2_accuracy.py: 25 m Hmax RMSE 4.25 m strong / 4.84 m all beams with
a bias calibration, ground 1.4 m; the fitted ground surface, better without noise, followed the
background photons below the ground there: Hmax 6.2 m, ground 5.4 m); ``mabel`` (density
filter, ground surface, p98 top, for dense airborne photons); ``atl08`` (the ATL08-style
classifier for noise, ground and canopy, DESIGN 1.11). :data:`RECOMMENDED_PRESET` names
the preset the project recommends and uses by default (:func:`default_estimators`).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, overload

import numpy as np

from ..errors import InputError, NoUsableDataError, SparseBlockWarning
from ..options import ESTIMATOR_PRESETS as _PRESET_NAMES
from ..options import RECOMMENDED_PRESET as _RECOMMENDED
from ..schema import LABEL_BETWEEN, LABEL_CANOPY, LABEL_GROUND, LABEL_NOISE
from .atl08_classify import CLASS_COLUMN, Atl08Params, classify_photons
from .density_filter import DensityParams, density_filter
from .ground_surface import GroundSurfaceParams, block_mean_ground, fit_ground_surface
from .grouped import percentile_by_group
from .params import BlockParams
from .plausibility import ImplausibleBlockWarning, flag_implausible_blocks
from .uncertainty import add_block_sigma, mark_use

if TYPE_CHECKING:
    import geopandas as gpd

    from ..photons import PhotonTrack
    from ..progress import Progress

__all__ = ["Estimators", "PRESETS", "preset", "estimate_blocks", "percentile_by_block",
           "GROUND_ESTIMATORS", "TOP_ESTIMATORS", "NOISE_ESTIMATORS", "RECOMMENDED_PRESET",
           "PRESET_NAMES", "default_estimators", "unused_k_sigma"]

log = logging.getLogger(__name__)

GroundEstimator = Literal["paper", "surface", "atl08"]
TopEstimator = Literal["paper", "p95", "p98", "p99", "p100", "atl08"]
NoiseEstimator = Literal["sigma", "conf", "density", "atl08", "none"]
GROUND_ESTIMATORS: tuple[str, ...] = ("paper", "surface", "atl08")
TOP_ESTIMATORS: tuple[str, ...] = ("paper", "p95", "p98", "p99", "p100", "atl08")
NOISE_ESTIMATORS: tuple[str, ...] = ("sigma", "conf", "density", "atl08", "none")


@dataclass(frozen=True)
class Estimators:
    """Which estimator computes each part of a block (DESIGN 1.10).

    Attributes
    ----------
    noise : "sigma", "conf", "density", "atl08" or "none"
        Default "atl08" (the recommended set: ``Estimators()`` is the ``atl08`` preset).
    ground : "paper", "surface" or "atl08" (needs noise "atl08")
        Default "atl08".
    top : "paper", "p95", "p98", "p99", "p100" or "atl08" (needs ground "atl08")
        Default "atl08".
    min_signal_conf : int
        ATL03 land confidence kept by ``noise="conf"`` (default 2, "low" and above).
    surface : GroundSurfaceParams
    density : DensityParams
    atl08 : Atl08Params
        The ATL08-style classifier's parameters (``noise="atl08"``).
    name : str
        The preset name these came from, or "custom".
    """

    noise: NoiseEstimator = "atl08"
    ground: GroundEstimator = "atl08"
    top: TopEstimator = "atl08"
    min_signal_conf: int = 2
    surface: GroundSurfaceParams = field(default_factory=GroundSurfaceParams)
    density: DensityParams = field(default_factory=DensityParams)
    atl08: Atl08Params = field(default_factory=Atl08Params)
    name: str = "custom"

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)
        for what, value, allowed in (("noise", self.noise, NOISE_ESTIMATORS),
                                     ("ground", self.ground, GROUND_ESTIMATORS),
                                     ("top", self.top, TOP_ESTIMATORS)):
            if value not in allowed:
                raise InputError(f"{what} estimator must be one of {', '.join(allowed)}; "
                                 f"got {value!r}")
        if self.ground == "atl08" and self.noise != "atl08":
            raise InputError(f"ground estimator 'atl08' needs noise 'atl08' (the classifier "
                             f"finds the ground surface); got noise {self.noise!r}: name the "
                             "ground and top too (the defaults are the classifier's), e.g. "
                             "ground='paper', top='paper' for the paper's")
        if (self.top == "atl08") != (self.ground == "atl08"):
            raise InputError(f"top 'atl08' and ground 'atl08' go together (canopy heights are "
                             f"taken above the classifier's ground); got ground "
                             f"{self.ground!r}, top {self.top!r}: name both (the defaults "
                             "are the classifier's)")
        if not (isinstance(self.min_signal_conf, int) and -2 <= self.min_signal_conf <= 4):
            raise InputError(f"min_signal_conf must be an integer -2..4, got "
                             f"{self.min_signal_conf!r}")

    @property
    def is_paper(self) -> bool:
        """True when every part is the paper's."""
        return (self.noise, self.ground, self.top) == ("sigma", "paper", "paper")

    def label(self) -> str:
        """Short description recorded with results, e.g. ``noise=density,ground=surface,top=p98``."""
        return f"noise={self.noise},ground={self.ground},top={self.top}"

    def percentile(self) -> float:
        """The top percentile (0-100) of a ``pNN`` top estimator."""
        if not self.top.startswith("p"):
            raise InputError(f"top estimator {self.top!r} is not a percentile")
        return float(self.top[1:])


PRESETS: dict[str, Estimators] = {
    "paper": Estimators(noise="sigma", ground="paper", top="paper", name="paper"),
    "icesat2": Estimators(noise="density", ground="paper", top="p98", name="icesat2"),
    "mabel": Estimators(noise="density", ground="surface", top="p98", name="mabel"),
    "atl08": Estimators(noise="atl08", ground="atl08", top="atl08", name="atl08"),
}

RECOMMENDED_PRESET = _RECOMMENDED
"""The estimator preset the project recommends, the default of every front end (declared
once with the preset names in the one vocabulary, ``canopyblocks.options``)."""

#: The preset names every front end offers (CLI ``--preset``, QGIS, Python), in one order.
PRESET_NAMES: tuple[str, ...] = _PRESET_NAMES
if set(PRESET_NAMES) != set(PRESETS):  # pragma: no cover - a preset added on one side only
    raise ImportError(f"blocks.estimators.PRESETS {sorted(PRESETS)} and "
                      f"options.ESTIMATOR_PRESETS {sorted(PRESET_NAMES)} differ")


def default_estimators() -> Estimators:
    """The estimators used when none are given: the recommended preset
    (:data:`RECOMMENDED_PRESET`, ``atl08``) for every sensor (measured on simulated MABEL
    photons, DESIGN 1.12, the ``atl08`` preset is the better one there too)."""
    return PRESETS[RECOMMENDED_PRESET]


def preset(name: str = RECOMMENDED_PRESET) -> Estimators:
    """The named preset (``paper``, ``icesat2``, ``mabel``, ``atl08``); default the
    recommended one, ``atl08``."""
    from ..arguments import check_instance
    check_instance(name, str, "preset: name", "a preset name (paper, icesat2, mabel, atl08)")
    try:
        return PRESETS[name]
    except KeyError:
        raise InputError(f"unknown preset {name!r}; use one of {', '.join(PRESETS)}") from None


#: What each estimator part uses instead of the paper's window (said when a cut-off is
#: refused), and what each noise filter is.
_INSTEAD = {"atl08": "the ATL08-style classifier's ground surface and canopy photons",
            "surface": "a robust along-track ground surface",
            "p95": "a height percentile", "p98": "a height percentile",
            "p99": "a height percentile", "p100": "the highest kept photon"}
_NOISE_FILTERS = {"conf": "ATL03's signal confidence", "density": "a photon-density filter",
                  "atl08": "the ATL08-style classifier", "none": "no filter"}
#: The command-line option naming each part of the estimators.
_PART_OPTION = {"noise": "--noise", "ground": "--ground-estimator", "top": "--top-estimator"}

_DEFAULT_K_SIGMA = BlockParams.__dataclass_fields__["k_sigma"].default


def _setter(est: Estimators, part: str) -> tuple[str, bool]:
    """The option or preset, as the user gave it, that set ``part`` of ``est`` to what it
    is, and whether it is a preset."""
    value = getattr(est, part)
    base = PRESETS.get(est.name.rstrip("+"), PRESETS["paper"])
    if getattr(base, part) != value or est.name not in PRESETS:
        return f"{_PART_OPTION[part]} {value}", False
    default = " (the default)" if est.name == RECOMMENDED_PRESET else ""
    return f"--preset {est.name}{default}", True


def _unused_because(est: Estimators, parts: list[str], options: list[str]) -> str:
    """What makes ``options`` inert (the option or preset that set ``parts`` to other than
    the paper's) and what to change."""
    setters = list(dict.fromkeys(_setter(est, p) for p in parts))
    names = " and ".join(options)
    them = "it" if len(options) == 1 else "them"
    which = " and ".join(s for s, _ in setters)
    fix = ("use --preset paper" if any(is_preset for _, is_preset in setters)
           else f"drop {which}")
    return f"{which} {'replaces' if len(setters) == 1 else 'replace'} {them}: {fix} for " \
           f"{names} to act, or drop {them}"


def unused_k_sigma(est: Estimators, k_sigma: float) -> str | None:
    """The refusal of a noise threshold ``k_sigma`` the estimators do not use (their
    noise filter is not the paper's sigma filter), or None when it acts."""
    if est.noise == "sigma":
        return None
    return (f"--k-sigma {k_sigma:g} is the threshold of the paper's noise filter (--noise "
            f"sigma), but these estimators filter noise with {_NOISE_FILTERS[est.noise]}; "
            + _unused_because(est, ["noise"], ["--k-sigma"]))


def refuse_unused_cutoffs(track: PhotonTrack, params: BlockParams, est: Estimators) -> None:
    """Refuse a top or ground cut-off, or a noise threshold ``k_sigma`` other than the
    default, that the estimators do not use (never ignore it).

    The cut-offs set the paper's windows: the top one is used by ``top="paper"`` only,
    the ground one by ``ground="paper"`` only; ``k_sigma`` by ``noise="sigma"`` only.

    Raises
    ------
    InputError
        Naming the option, what the estimators use instead and the option or preset to
        change for it to act.
    """
    where = f"track {track.track} ({track.source or 'in memory'})"
    if params.k_sigma != _DEFAULT_K_SIGMA and (why := unused_k_sigma(est, params.k_sigma)):
        raise InputError(f"{where}: {why}")
    unused = [(option, part) for option, value, part in (
        ("--top-cutoff", params.top_cutoff, "top"),
        ("--ground-cutoff", params.ground_cutoff, "ground"))
        if value is not None and getattr(est, part) != "paper"]
    if not unused:
        return
    options, parts = [o for o, _ in unused], [p for _, p in unused]
    instead = " and ".join(dict.fromkeys(_INSTEAD.get(getattr(est, p), getattr(est, p))
                                         for p in parts))
    raise InputError(
        f"{where}: {' and '.join(options)} {'sets' if len(options) == 1 else 'set'} the "
        f"paper's {' and '.join(parts)} window{'s' * (len(parts) > 1)}, but these "
        f"estimators use {instead}; " + _unused_because(est, parts, options))


def percentile_by_block(block: np.ndarray, z: np.ndarray, q: float,
                        n_blocks: int) -> np.ndarray:
    """Per block, the ``q``-th percentile (0-100) of ``z`` (numpy's linear method).

    ``block`` holds integer indices 0..n_blocks-1; blocks without values give NaN.
    """
    return percentile_by_group(block, z, q, n_blocks)


def _paper_params(params: BlockParams, est: Estimators) -> BlockParams:
    if est.noise == "sigma":
        return params
    if est.noise == "conf":
        return replace(params, noise="none", min_signal_conf=est.min_signal_conf)
    return replace(params, noise="none")


@overload
def estimate_blocks(track: PhotonTrack, params: BlockParams | None = ...,
                    estimators: Estimators | None = ..., *, labels: Literal[False] = ...,
                    progress: Progress | None = ...) -> gpd.GeoDataFrame: ...


@overload
def estimate_blocks(track: PhotonTrack, params: BlockParams | None = ...,
                    estimators: Estimators | None = ..., *, labels: Literal[True],
                    progress: Progress | None = ...
                    ) -> tuple[gpd.GeoDataFrame, dict[float, np.ndarray]]: ...


def estimate_blocks(track: PhotonTrack, params: BlockParams | None = None,
                    estimators: Estimators | None = None, *, labels: bool = False,
                    progress: Progress | None = None
                    ) -> gpd.GeoDataFrame | tuple[gpd.GeoDataFrame, dict[float, np.ndarray]]:
    """Block table with the chosen estimators (the paper's engine when all are ``paper``).

    Parameters
    ----------
    track : PhotonTrack
    params : BlockParams, optional
        Lengths, ``s0``, ``min_photons`` and the paper's settings (used by its parts).
    estimators : Estimators, optional
        Default: the recommended ones (:func:`default_estimators`, the ``atl08`` preset);
        ``preset("paper")`` for the paper's method.
    labels : bool
        Also return per-photon labels per length (noise / ground / canopy / between;
        with ``ground="surface"``, ground = the photons the surface was fitted to).
    progress : Progress, optional

    Returns
    -------
    GeoDataFrame (and labels)
        The DESIGN 5 block columns plus ``estimators`` (the :meth:`Estimators.label`).
    """
    from ..arguments import check_instance, check_optional
    from ..photons import PhotonTrack
    check_instance(track, PhotonTrack, "estimate_blocks: track")
    check_optional(params, BlockParams, "estimate_blocks: params")
    check_optional(
        estimators,
        Estimators,
        "estimate_blocks: estimators",
        "an Estimators (e.g. preset('icesat2')) or None",
    )
    from .engine import compute_blocks

    params = BlockParams() if params is None else params
    est = default_estimators() if estimators is None else estimators
    if not isinstance(est, Estimators):
        raise InputError(f"estimators must be an Estimators (or a preset name via preset()); "
                         f"got {type(est).__name__}")
    refuse_unused_cutoffs(track, params, est)
    work = track
    removed = None
    if est.noise == "atl08":
        from .atl08_blocks import refuse_signal_conf
        refuse_signal_conf(track, params)  # never silently ignored
        classes = classify_photons(track, est.atl08)  # after the background-rate check
        if labels:  # the photon layer's ATL08-style column (classed_pc_flag)
            track.extra[CLASS_COLUMN] = classes.classes
        if est.ground == "atl08":
            from .atl08_blocks import atl08_block_table

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SparseBlockWarning)
                warnings.simplefilter("ignore", ImplausibleBlockWarning)
                blocks, lab = atl08_block_table(track, params, classes, labels=labels,
                                                progress=progress)
            _warn_sparse(blocks, track.track, params.min_photons)
            blocks["estimators"] = est.label()
            flag_implausible_blocks(blocks, track.track)
            add_block_sigma(blocks, track, classes)  # hmax_sigma, ground_sigma, use
            return (blocks, lab) if labels else blocks
        removed = classes.classes <= 0
        work = track.subset(~removed)
    if est.noise == "conf" and track.signal_conf is None:
        raise InputError(f"noise='conf' needs ATL03 signal_conf_ph, which track {track.track} "
                         "lacks; use noise='density' for MABEL, simulated or table photons")
    if est.noise == "density":
        res = density_filter(track.s, track.h, est.density)
        removed = ~res.keep
        log.info("track %s: density filter removed %.1f %% of %d photons (background %.3g "
                 "photons/m^2)", track.track, 100 * res.background_share, len(track),
                 float(np.median(res.rate)) if res.rate.size else 0.0)
        work = track.subset(res.keep)
    if removed is not None and len(track) and not len(work):
        what = "the ATL08-style classifier" if est.noise == "atl08" else "the density filter"
        raise NoUsableDataError(
            f"track {track.track} ({track.source or 'in memory'}): all {len(track):,} photons "
            f"were classed noise by {what} (noise={est.noise!r}); no blocks -- a beam in "
            "cloud, or a background rate the photons cannot stand out of")
    bp = _paper_params(params, est)
    paper_only = est.ground == "paper" and est.top == "paper"
    with warnings.catch_warnings():
        if not paper_only:  # flagged below, on the estimators' own heights
            warnings.simplefilter("ignore", ImplausibleBlockWarning)
        blocks, lab = compute_blocks(work, bp, labels=True, progress=progress)
    if paper_only:
        blocks["estimators"] = est.label()
        if labels:
            return blocks, {k: _expand(v, removed) for k, v in lab.items()}
        return blocks
    blocks = blocks.copy()
    out_labels: dict[float, np.ndarray] = {}
    surface = None
    if est.ground == "surface":
        any_kept = np.zeros(len(work), bool)
        for v in lab.values():
            any_kept |= (v != LABEL_NOISE) & (v >= 0)
        surface = fit_ground_surface(work.s[any_kept], work.h[any_kept], est.surface)
    for length, lv in lab.items():
        rows = np.flatnonzero(blocks["length"].to_numpy() == length)
        sub = blocks.iloc[rows]
        kept = (lv != LABEL_NOISE) & (lv >= 0)
        s0 = float(sub["s_start"].iloc[0] - sub["block"].iloc[0] * length) if len(sub) else 0.0
        bidx = np.floor((work.s - s0) / length)
        # map block numbers to table rows
        nums = sub["block"].to_numpy()
        pos = np.searchsorted(nums, bidx)
        inrow = kept & (pos < len(nums)) & (nums[np.minimum(pos, len(nums) - 1)] == bidx)
        prow = pos[inrow]
        z = work.h[inrow]
        if surface is not None:
            ground = block_mean_ground(surface, sub["s_start"].to_numpy(float),
                                       sub["s_end"].to_numpy(float))
        else:
            ground = sub["ground"].to_numpy(float)
        if est.top != "paper":
            top = percentile_by_block(prow, z, est.percentile(), len(sub))
        else:
            top = sub["top"].to_numpy(float)
        z90, n_between = _z90(prow, z, ground, top, len(sub))
        n_kept = np.bincount(prow, minlength=len(sub))
        sparse = n_kept < params.min_photons
        inverted = ~sparse & ((top <= ground) | (n_between == 0))
        top = np.where(sparse, np.nan, top)
        ground = np.where(sparse, np.nan, ground)
        z90 = np.where(sparse, np.nan, z90)
        idx = blocks.index[rows]
        blocks.loc[idx, "n_kept"] = n_kept
        blocks.loc[idx, "n_between"] = np.where(sparse, 0, n_between)
        blocks.loc[idx, "top"] = top
        blocks.loc[idx, "ground"] = ground
        blocks.loc[idx, "hmax"] = top - ground
        blocks.loc[idx, "z90"] = z90
        blocks.loc[idx, "h90"] = z90 - ground
        blocks.loc[idx, "flag"] = np.where(sparse, "sparse",
                                           np.where(inverted, "inverted", "ok"))
        if labels:
            new = np.where(kept, LABEL_BETWEEN, lv).astype(np.int8)
            full_top = np.full(len(work), np.inf)
            full_ground = np.full(len(work), -np.inf)
            full_top[np.flatnonzero(inrow)] = top[prow]
            full_ground[np.flatnonzero(inrow)] = ground[prow]
            if surface is not None:
                near = kept & (np.abs(work.h - surface(work.s)) <= est.surface.band)
            else:
                near = kept & (work.h <= full_ground)
            new[kept & (work.h >= full_top)] = LABEL_CANOPY
            new[near] = LABEL_GROUND
            out_labels[length] = _expand(new, removed)
    blocks["estimators"] = est.label()
    flag_implausible_blocks(blocks, track.track)
    mark_use(blocks)  # no sigma model for these estimators (NaN): use = flag ok
    if labels:
        return blocks, out_labels
    return blocks


def _warn_sparse(blocks: gpd.GeoDataFrame, track_id: str, min_photons: int) -> None:
    n = int((blocks["flag"] == "sparse").sum())
    if n:
        warnings.warn(f"track {track_id}: {n} of {len(blocks)} blocks hold fewer than "
                      f"min_photons={min_photons} signal photons; they are flagged 'sparse' "
                      "with NaN metrics", SparseBlockWarning, stacklevel=3)


def _expand(lab: np.ndarray, removed: np.ndarray | None) -> np.ndarray:
    """Labels of a density-filtered track back onto every photon (removed = noise)."""
    if removed is None:
        return lab
    out = np.full(removed.size, LABEL_NOISE, np.int8)
    out[~removed] = lab
    return out


def _z90(prow: np.ndarray, z: np.ndarray, ground: np.ndarray, top: np.ndarray,
         n_blocks: int) -> tuple[np.ndarray, np.ndarray]:
    """Paper's z90 of the photons with ground <= z <= top, per block; and their count."""
    g = ground[prow]
    t = top[prow]
    with np.errstate(invalid="ignore"):
        between = (z >= g) & (z <= t)
    pb, zb = prow[between], z[between]
    order = np.lexsort((zb, pb))
    pb, zb = pb[order], zb[order]
    counts = np.bincount(pb, minlength=n_blocks)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.full(n_blocks, np.nan)
    has = counts > 0
    k = np.floor(0.9 * (counts[has] - 1)).astype(np.int64)
    out[has] = zb[starts[has] + k]
    return out, counts


