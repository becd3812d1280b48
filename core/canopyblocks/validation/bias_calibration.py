"""Bias calibration of block heights (DESIGN 1.10): fitted on one set, applied to another.

Most of the error of every estimator on sparse photons is bias (DESIGN 1.10: calibrated
on other tiles of the same forest, every estimator reaches Hmax RMSE about 2.7-3.0 m at
25 m). This module fits, per block length and beam strength, a correction of the
heights above ground, ``hmax' = a * hmax + b`` and ``h90' = a90 * h90 + b90`` (additive:
``a = 1``), against reference blocks; the absolute heights follow (``top' = ground +
hmax'``, ``z90' = ground + h90'``), so the corrected table stays consistent.

The two corrections are fitted apart, so on a block whose H90 lies close to its Hmax the
corrected H90 can exceed the corrected Hmax (measured on the README's example: 3 of 10
blocks at 25 m, Hmax +7.18 m, H90 +9.58 m), and a negative correction can put the top
below the ground.  Neither can be: a corrected block keeps ``0 <= h90 <= hmax`` (so
``ground <= z90 <= top``) by bounding the corrected values, and such a block is marked
``bias:<kind>:bounded`` in the ``calibration`` column (a warning gives the count).

The held-out error is a parity split by block index: corrections fitted on the even
blocks are scored on the odd ones and the other way round, pooled. The file records what
the correction is only valid for: the estimators (preset), block lengths, beam
strengths, the photons' background level, corridor width and reference kind; applying
it to blocks made with other estimators is refused.
"""

from __future__ import annotations

import json
import logging
import os
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from ..atomic import atomic_output
from ..errors import CanopyBlocksWarning, FileFormatError, InputError, NoUsableDataError

__all__ = ["BiasModel", "BiasCalibration", "fit_bias_calibration", "apply_bias_calibration",
           "read_bias_calibration", "write_bias_calibration", "CALIBRATED_METRICS"]

log = logging.getLogger(__name__)

BiasKind = Literal["additive", "linear"]
#: Metrics corrected (heights above ground); top and z90 follow from them.
CALIBRATED_METRICS: tuple[str, ...] = ("hmax", "h90")
_FORMAT = "canopyblocks-bias-calibration/1"
_MIN_BLOCKS = 6
#: What a table without an ``estimators`` column was made with (the paper's estimators).
_PAPER_LABEL = "noise=sigma,ground=paper,top=paper"


def _same_estimators(a: str, b: str) -> bool:
    """Labels naming the same estimators (parts in any order; ``paper`` = the paper's)."""
    def parts(label: str) -> frozenset[str]:
        label = _PAPER_LABEL if label.strip() == "paper" else label
        return frozenset(p.strip() for p in label.split(",") if p.strip())
    return parts(a) == parts(b)


@dataclass(frozen=True)
class BiasModel:
    """``corrected = slope * estimate + intercept`` for one metric, length and strength.

    ``rmse_before``/``rmse_after`` are in-sample; ``holdout_rmse_before``/
    ``holdout_rmse_after`` come from the parity split (m).
    """

    metric: str
    length: float
    strength: str
    slope: float
    intercept: float
    n: int
    rmse_before: float
    rmse_after: float
    holdout_rmse_before: float
    holdout_rmse_after: float
    n_holdout: int


@dataclass(frozen=True)
class BiasCalibration:
    """A fitted bias calibration and what it is valid for."""

    models: tuple[BiasModel, ...]
    kind: BiasKind
    estimators: str
    preset: str = "custom"
    strengths: tuple[str, ...] = ("all",)
    noise_level: float | None = None
    corridor_width: float | None = None
    reference: str = "corridor"
    sources: tuple[str, ...] = field(default_factory=tuple)

    def model(self, metric: str, length: float, strength: str) -> BiasModel:
        """The model for ``metric`` at ``length`` (m) and ``strength``.

        Raises
        ------
        InputError
            No model was fitted for that length/strength.
        """
        for m in self.models:
            if m.metric == metric and np.isclose(m.length, length) and \
                    m.strength in (strength, "all"):
                return m
        have = sorted({(m.length, m.strength) for m in self.models})
        raise InputError(f"the bias calibration has no {metric} model for {length:g} m blocks "
                         f"of {strength} beams (it has {have}); refit it with these lengths")

    def table(self) -> pd.DataFrame:
        """One row per model (for the CSV summary)."""
        return pd.DataFrame([asdict(m) for m in self.models])


def _fit(est: np.ndarray, ref: np.ndarray, kind: BiasKind) -> tuple[float, float]:
    if kind == "additive" or est.size < 3 or np.ptp(est) == 0:
        return 1.0, float(np.mean(ref - est))
    slope, intercept = np.polyfit(est, ref, 1)
    return float(slope), float(intercept)


def _rmse(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v))) if v.size else float("nan")


def _check_strengths(strengths: object, name: str) -> None:
    """``strengths`` is None or a mapping of track -> "strong"/"weak"."""
    if strengths is None:
        return
    if not isinstance(strengths, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in strengths.items()):
        raise InputError(f"{name}: strengths must map each track to its beam strength, e.g. "
                         f"{{'gt1l': 'strong', 'gt1r': 'weak'}}; got {str(strengths)[:60]!r}")


def fit_bias_calibration(residuals: pd.DataFrame, *, kind: BiasKind = "additive",
                         strengths: dict[str, str] | None = None, preset: str = "custom",
                         noise_level: float | None = None,
                         corridor_width: float | None = None, reference: str = "corridor",
                         sources: tuple[str, ...] = ()) -> BiasCalibration:
    """Fit hmax and h90 corrections against reference blocks.

    Parameters
    ----------
    residuals : DataFrame
        Validated blocks: ``track``, ``length``, ``block``, ``hmax``, ``h90``,
        ``ref_hmax``, ``ref_h90``, ``estimators`` and a boolean ``use`` (or ``flag``).
    kind : "additive" or "linear"
    strengths : dict, optional
        Track -> beam strength (``"strong"``/``"weak"``); models are then fitted per
        strength. None: one model for all tracks.
    preset, noise_level, corridor_width, reference, sources
        Recorded with the calibration.

    Raises
    ------
    NoUsableDataError
        Fewer than 6 usable blocks for a length/strength.
    """
    from ..arguments import check_frame, check_reference_metres
    check_frame(residuals, "fit_bias_calibration: residuals", "validated blocks (the residuals table of a validation)")
    for m in [c for c in CALIBRATED_METRICS if {c, f"ref_{c}"} <= set(residuals.columns)]:
        check_reference_metres(residuals[m].to_numpy(float), residuals[f"ref_{m}"].to_numpy(float),
                               m, f"ref_{m}", "fit_bias_calibration")
    if kind not in ("additive", "linear"):
        raise InputError(f"kind must be 'additive' or 'linear', got {kind!r}")
    _check_strengths(strengths, "fit_bias_calibration")
    need = {"track", "length", "block", "hmax", "h90", "ref_hmax", "ref_h90"}
    missing = need - set(residuals.columns)
    if missing:
        raise InputError(f"the validated blocks lack {', '.join(sorted(missing))}; pass the "
                         "residuals of a validation")
    from ..blocks.uncertainty import upgrade_table

    df = residuals if "use" in residuals.columns else upgrade_table(residuals.copy())
    df = df[df["use"].to_numpy(bool)]
    labels = (df["estimators"].unique() if "estimators" in df.columns
              else np.array([_PAPER_LABEL]))
    if len(labels) > 1:
        raise InputError(f"the blocks were made with several estimators ({', '.join(labels)}); "
                         "fit one calibration per estimator set")
    estimators = str(labels[0]) if len(labels) else _PAPER_LABEL
    strength = (df["track"].map(strengths).fillna("unknown").to_numpy()
                if strengths else np.full(len(df), "all", dtype=object))
    models = []
    for length in sorted(df["length"].unique()):
        for st in sorted(set(strength.tolist())):
            sel = (df["length"].to_numpy() == length) & (strength == st)
            sub = df[sel]
            for metric in CALIBRATED_METRICS:
                est = sub[metric].to_numpy(float)
                ref = sub[f"ref_{metric}"].to_numpy(float)
                ok = np.isfinite(est) & np.isfinite(ref)
                est, ref = est[ok], ref[ok]
                parity = sub["block"].to_numpy()[ok] % 2
                if est.size < _MIN_BLOCKS:
                    raise NoUsableDataError(
                        f"{est.size} usable {length:g} m blocks of {st} beams for the {metric} "
                        f"calibration; at least {_MIN_BLOCKS} are needed")
                a, b = _fit(est, ref, kind)
                held: list[np.ndarray] = []
                held_before: list[np.ndarray] = []
                for p in (0, 1):
                    fit_on, score_on = parity == p, parity != p
                    if fit_on.sum() < 2 or score_on.sum() == 0:
                        continue
                    ap, bp = _fit(est[fit_on], ref[fit_on], kind)
                    held.append(ap * est[score_on] + bp - ref[score_on])
                    held_before.append(est[score_on] - ref[score_on])
                h = np.concatenate(held) if held else np.zeros(0)
                hb = np.concatenate(held_before) if held_before else np.zeros(0)
                models.append(BiasModel(
                    metric=metric, length=float(length), strength=str(st), slope=a,
                    intercept=b, n=int(est.size), rmse_before=_rmse(est - ref),
                    rmse_after=_rmse(a * est + b - ref), holdout_rmse_before=_rmse(hb),
                    holdout_rmse_after=_rmse(h), n_holdout=int(h.size)))
    if not models:
        raise NoUsableDataError("no usable validated blocks to fit a bias calibration")
    return BiasCalibration(tuple(models), kind, estimators, preset,
                           tuple(sorted(set(strength.tolist()))), noise_level, corridor_width,
                           reference, tuple(str(s) for s in sources))


def apply_bias_calibration(blocks: pd.DataFrame, cal: BiasCalibration, *,
                           strengths: dict[str, str] | None = None,
                           source: str = "the calibration") -> pd.DataFrame:
    """A copy of ``blocks`` with hmax/h90 corrected and top/z90 following.

    Adds ``calibration``: ``"bias:<kind>"``, or ``"bias:<kind>:bounded"`` for a block whose
    corrected values had to be bounded to ``0 <= h90 <= hmax`` (top not below the ground,
    H90 not above Hmax; a :class:`~canopyblocks.errors.CanopyBlocksWarning` gives the
    count).  Refuses blocks made with other estimators than the calibration, and lengths
    or strengths it has no model for.
    """
    from ..arguments import check_frame, check_instance
    check_frame(blocks, "apply_bias_calibration: blocks", "a block table (DataFrame)")
    check_instance(cal, BiasCalibration, "apply_bias_calibration: cal", "a BiasCalibration (fit_bias_calibration or read_bias_calibration)")
    _check_strengths(strengths, "apply_bias_calibration")
    label = (str(blocks["estimators"].iloc[0]) if "estimators" in blocks.columns and len(blocks)
             else _PAPER_LABEL)
    if "estimators" in blocks.columns and blocks["estimators"].nunique() > 1:
        raise InputError("the blocks were made with several estimator sets; calibrate each")
    if not _same_estimators(label, cal.estimators):
        raise InputError(
            f"{source} was fitted on blocks made with {cal.estimators} (preset {cal.preset}) "
            f"but these blocks were made with {label}; use the same estimators/preset or "
            "refit the calibration")
    out = blocks.copy()
    strength = (out["track"].map(strengths).fillna("unknown").to_numpy()
                if strengths else np.full(len(out), "all", dtype=object))
    if "all" in cal.strengths:
        strength = np.full(len(out), "all", dtype=object)
    ground = out["ground"].to_numpy(float)
    corrected = {}
    for metric in ("hmax", "h90"):
        vals = out[metric].to_numpy(float).copy()
        for length in np.unique(out["length"].to_numpy(float)):
            for st in np.unique(strength):
                sel = (out["length"].to_numpy(float) == length) & (strength == st)
                m = cal.model(metric, float(length), str(st))
                vals[sel] = m.slope * vals[sel] + m.intercept
        corrected[metric] = vals
    hmax, h90 = corrected["hmax"], corrected["h90"]
    with np.errstate(invalid="ignore"):
        bounded = (hmax < 0) | (h90 < 0) | (h90 > hmax)
        hmax = np.where(hmax < 0, 0.0, hmax)
        h90 = np.clip(h90, 0.0, hmax)
    out["hmax"], out["top"] = hmax, ground + hmax
    out["h90"], out["z90"] = h90, ground + h90
    out["calibration"] = np.where(bounded, f"bias:{cal.kind}:bounded", f"bias:{cal.kind}")
    if bounded.any():
        warnings.warn(
            f"{int(bounded.sum())} of {len(out)} calibrated blocks had H90 above Hmax or the "
            "top below the ground after the correction (the Hmax and H90 corrections are "
            "fitted apart); they were bounded to 0 <= H90 <= Hmax and are marked "
            f"'bias:{cal.kind}:bounded' in the calibration column",
            CanopyBlocksWarning, stacklevel=2)
    return out


def write_bias_calibration(cal: BiasCalibration, path: str | os.PathLike[str]) -> Path:
    """Write the calibration as JSON (atomic), and a CSV summary beside it."""
    from ..arguments import check_instance, check_path
    check_instance(cal, BiasCalibration, "write_bias_calibration: cal", "a BiasCalibration (fit_bias_calibration)")
    check_path(path, "write_bias_calibration: path", "a JSON file path")
    p = Path(path)
    doc = {"format": _FORMAT, "kind": cal.kind, "estimators": cal.estimators,
           "preset": cal.preset, "strengths": list(cal.strengths),
           "noise_level": cal.noise_level, "corridor_width": cal.corridor_width,
           "reference": cal.reference, "sources": list(cal.sources),
           "models": [asdict(m) for m in cal.models]}
    with atomic_output(p) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2, allow_nan=True), encoding="utf-8")
    csv = p.with_suffix(".csv")
    with atomic_output(csv) as tmp:
        cal.table().to_csv(tmp, index=False)
    return p


def read_bias_calibration(path: str | os.PathLike[str]) -> BiasCalibration:
    """Read a calibration written by :func:`write_bias_calibration`.

    Raises
    ------
    FileFormatError
        Missing, unreadable or not a canopyblocks bias calibration.
    """
    from ..arguments import check_path
    check_path(path, "read_bias_calibration: path", "a calibration JSON path")
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileFormatError(f"calibration {p}: no such file") from None
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"calibration {p}: not readable JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != _FORMAT:
        raise FileFormatError(f"calibration {p} is not a canopyblocks bias calibration "
                              f"(expected format {_FORMAT}); fit one with "
                              "`canopyblocks calibrate --method bias`")
    try:
        models = tuple(BiasModel(**m) for m in doc["models"])
        return BiasCalibration(models, doc["kind"], doc["estimators"], doc.get("preset",
                               "custom"), tuple(doc.get("strengths", ["all"])),
                               doc.get("noise_level"), doc.get("corridor_width"),
                               doc.get("reference", "corridor"), tuple(doc.get("sources", [])))
    except (KeyError, TypeError) as exc:
        raise FileFormatError(f"calibration {p}: malformed ({exc})") from None
