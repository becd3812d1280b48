"""Plain words for the chain's reports: the glossary section at the end, and the
sentence saying which tiles fitted the estimators and the sigma model.

Every term a report uses that a user cannot look up is explained here in one line;
a report lists the terms it uses (:func:`glossary_section`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ...outputs.report import ReportSection

__all__ = ["GLOSSARY", "glossary_section", "training_sentence", "training_caveat",
           "CALIBRATION_TILES",
           "UNSEEN_FIGURES", "UNSEEN_CONDITION", "GEDI_GLOSSARY", "gedi_glossary_section"]

#: The tiles the recommended estimators' windows and the per-block sigma model were
#: fitted on (the package's ``blocks/uncertainty_model.json`` names them too).
CALIBRATION_TILES: tuple[str, ...] = ("lasR_bcts_1", "lasR_bcts_2")

#: The condition the unseen-tile figures hold under (the accuracy benchmark's): the
#: ``atl08`` estimators plus an additive bias calibration per beam strength and night/day
#: fitted on the bundled calibration tiles.
UNSEEN_CONDITION = (
    "for the 'atl08' estimators plus an additive bias calibration (per beam strength and "
    "night/day) fitted on the calibration tiles")

#: What the recommended estimators (with a bias calibration) and their sigma scored on
#: three airborne tiles never used for fitting (lidR_Topography, pyfor_test,
#: lidR_MixedConifer), simulated night and day, 25 m blocks: the project's accuracy and
#: block-sigma benchmarks (measured elsewhere, not on this run).
UNSEEN_FIGURES = (
    f"{UNSEEN_CONDITION}: Hmax RMSE against the footprint-matched reference 1.9 m (strong beams, night) to "
    "3.0 m (strong, day) and 4.6 to 8.6 m (weak beams); ground RMSE 0.8 to 1.1 m "
    "(strong beams); the predicted sigma held for about 80 % of the Hmax residuals "
    "within 1 sigma and 96 % within 2 sigma")

#: term -> one line.
GLOSSARY: dict[str, str] = {
    "block": "a stretch of the track of the stated length (10, 25, 50 m ...); its heights "
             "come from the photons inside it.",
    "Hmax": "canopy height of a block (the recommended estimators): the 98th percentile "
            "of the heights of its canopy "
            "photons (those more than 0.6 m above the ground surface) above that surface, "
            "metres; it grows with the block's length, as a longer block holds taller "
            "trees.",
    "RH98": "relative height 98: the height above the ground below which 98 % of the "
            "return energy (or of the airborne points, weighted as the footprint) lies.",
    "footprint-matched airborne reference": "the airborne points seen as the sensor sees "
            "them: footprints of the sensor's size every 0.7 m along the block, each point "
            "weighted by the footprint (a Gaussian). Its ground is the mean over the "
            "footprints of the weighted ground points; its Hmax and h90 are the block's own "
            "statistic of those points (statistic 'pooled', the default): the 98th and 90th "
            "percentile of the heights above each footprint's ground plane of the points "
            "more than 0.6 m above it, pooled over all the block's footprints, each "
            "footprint counting once; its top is ground + Hmax. The like-with-like "
            "reference: the same statistic, of the same kind of returns, at every block "
            "length. The residual tables name the statistic (column ref_statistic).",
    "footprint-mean": "the reference statistic of earlier releases, kept by that name "
            "(--reference-statistic footprint-mean): the mean over the block's footprints "
            "of each footprint's RH98 (RH90) of all its points, ground included. It does "
            "not grow with the block's length, so against it the bias of Hmax changes with "
            "the length.",
    "corridor maximum": "the highest DSM cell and the mean DTM cell of the corridor (the "
            "cells a strip of the corridor width along the block touches): the paper's "
            "reference; it sits above what sparse photons can see.",
    "bias": "mean of the residuals (value minus reference value), metres.",
    "RMSE": "root mean square of the residuals, metres.",
    "95 % interval": "the range that holds the true bias (or RMSE) with 95 % confidence: "
            "for blocks a block bootstrap along the track, per block length (2,000 "
            "resamples of runs of adjacent blocks 100 m long -- 10 blocks of 10 m, 4 of "
            "25 m, 2 of 50 m -- as neighbouring blocks share terrain and canopy; from a "
            "fixed random state so the same data give the same interval); for footprints a "
            "bootstrap over the footprints; the analytic interval above 5,000 blocks.",
    "R²": "the squared correlation of the values and the reference values (of the "
          "least-squares line), 0 to 1.",
    "sigma (hmax_sigma, ground_sigma)": "the predicted 1-sigma error of a block's Hmax or "
            "ground, metres, from the block's photon counts, noise and terrain.",
    "low_confidence": "a block whose predicted sigma is too wide to be useful; written, "
            "but left out of the statistics.",
    "sparse": "a block with too few photons for a height; written with no value.",
    "reference outside": "a block only partly covered by the airborne points: one of its "
            "footprints has less than 90 % of its circle over cells holding airborne points "
            "(or its corridor reaches beyond the rasters) -- it runs past the tiles' edge or "
            "over a data gap. Its reference values are computed from the part covered, "
            "but it is left out of the statistics.",
    "implausible": "a block whose canopy height is taller than any tree.",
    "left out": "a block written but not in the statistics has one reason, the first "
            "that applies in this order: reference outside (or reference nodata, "
            "no_ground, missing: the reference cannot judge it, whatever its photons "
            "gave), sparse, inverted, implausible, low_confidence (the block's own flag), "
            "not used, no value. The same reason in every section of the report and in "
            "the column 'reason' of every residuals layer; the table of blocks written "
            "counts the blocks' own flags, before any reference.",
    "aspect class": "the compass direction the terrain faces (downhill), N to NW in 45 "
            "degree sectors; flat = mean terrain slope below 2 degrees.",
    "slope class": "mean terrain slope of the block's corridor in degrees (2 m DTM, "
            "Horn's method): 0-5, 5-10, 10-20, 20-30, >30 degrees.",
    "photon rate": "the mean number of signal photons per laser shot of the simulation "
            "(Poisson mean: 'boreal' 1.0, 'temperate' 1.9, 'tropical' 0.6), the strong-beam "
            "rates ICESat-2 records over such forests.",
    "random seed": "the number that starts the random draws of a simulation: the same "
            "seed gives the same photons or waveforms.",
    "pseudo-waveform": "the airborne points of a footprint binned by height and weighted "
            "by the footprint, as a waveform lidar would record them.",
    "step classifier": "the simulation study's own simple classifier, applied to the "
            "photons of one footprint in steps of 20 photons: ground = the photons below the "
            "lowest photon plus 3 PSF widths, canopy top = those above the highest photon "
            "minus 1 m.",
    "PSF width": "the standard deviation of the sensor's pulse in height (the point "
            "spread function), metres.",
    "window floor": "the paper's method takes the ground (canopy top) as the photons of a "
            "window above the lowest (below the highest) kept photon, sized by its cut-off; "
            "the window cannot shrink below its smallest size, so on sparse photons its "
            "ground sits above the lowest photon and its top below the highest.",
    "cut-off": "the fraction of a block's photons the paper's method takes as its ground "
            "(or canopy-top) window.",
    "held out": "scored on blocks not used for the fit: fitted on the even blocks, "
            "scored on the odd ones, and the other way round.",
    "ALS": "airborne laser scanning: the airborne lidar tiles the reference comes from.",
    "L1B / L2A": "GEDI's waveform product (L1B) and its heights product (L2A), whose "
            "algorithm the chain applies to the waveforms.",
    "cover": "canopy cover: the share of the footprint's returns more than 2 m above the "
             "ground, a fraction 0 to 1.",
    "inverted": "a block whose canopy top came out below its ground (a negative height); "
                "left out of the statistics.",
    "h90": "the height above the ground below which 90 % of a block's canopy photons (or "
           "of the reference's canopy points, pooled over the block's footprints) lie, "
           "metres.",
    "top": "canopy top: the block's ground plus its Hmax (elevation, metres), for the "
           "estimate and the reference alike; a longer block's top can lie above or below "
           "that of a shorter block inside it, as its Hmax is a percentile of more "
           "photons.",
    "MAE": "mean absolute error: the mean of the residuals' absolute values, metres.",
    "OLS": "ordinary least squares: the straight-line fit of the values on the reference "
           "values.",
    "fit slope": "the slope of the least-squares line of the values on the reference "
                 "values, metres per metre (1 = no scale error); not the terrain slope, "
                 "which is in degrees.",
    "ATL03": "ICESat-2's geolocated photon product: every photon's position and height.",
    "ATL08-style": "the estimators that follow ICESat-2's ATL08 land and vegetation "
                   "product: photons classified as ground, canopy and canopy top, the "
                   "ground a surface through the ground photons.",
    "MABEL": "the Multiple Altimeter Beam Experimental Lidar: NASA's airborne "
             "photon-counting lidar, ICESat-2's precursor, for whose dense photons the "
             "paper's method was built.",
    "DSM / DTM": "digital surface model (the top of the canopy, buildings, ground) and "
                 "digital terrain model (the bare ground), rasters made from the airborne "
                 "points.",
    "beam names (gt1l ... gt3r)": "ICESat-2's six beams: ground tracks 1 to 3, left (l) "
                                  "and right (r); which of a pair is strong depends on "
                                  "the spacecraft's orientation. GEDI's beams are named "
                                  "BEAM0000 ... BEAM1011.",
    "beam strength": "ICESat-2's strong beams carry about four times the energy of the "
                     "weak ones, so they record about four times the photons.",
    "setting a1": "one of the GEDI L2A algorithm's settings groups (a1 ... a6): its noise "
                  "thresholds and smoothing widths for finding the signal and the modes.",
    "lowest mode": "the lowest peak of a waveform above the noise: GEDI L2A's ground.",
    "penetration": "how far below the canopy top a waveform's energy reaches: whether the "
                   "ground was seen.",
}

#: A GEDI run's words where they differ from the photon reports' (``definition`` of the
#: footprint reference: "waveform" or "points").
GEDI_GLOSSARY: dict[str, dict[str, str]] = {
    "waveform": {
        "footprint-matched airborne reference": "the airborne points under each GEDI "
            "footprint formed into the waveform the sensor would record (a Gaussian beam of "
            "the footprint's size, each return's energy, the pulse; no noise) and read by "
            "the same GEDI L2A algorithm as the GEDI waveforms: ground = its lowest mode, "
            "RH98 and cover from its energy; the like-with-like reference.",
        "cover": "canopy cover: the canopy share of a footprint's return energy (canopy "
                 "energy over all the energy of the signal), for the GEDI waveform and the "
                 "reference waveform alike; a fraction 0 to 1.",
        "RH98": "relative height 98: the height above the ground (the lowest mode) below "
                "which 98 % of the waveform's return energy lies, metres.",
    },
    "points": {
        "footprint-matched airborne reference": "the airborne points under each GEDI "
            "footprint weighted by the footprint (a Gaussian of the footprint's size): "
            "ground = the weighted mean of the ground points, RH98 = the weighted 98th "
            "percentile of all returns above it; the like-with-like reference.",
    },
    "": {
        "independent airborne quantities": "what the airborne points themselves show under "
            "a footprint (the class-2 ground, percentiles of the point heights above it), "
            "with no model of the sensor: the comparison a result is judged by.",
        "round trip": "a simulated file read back and compared with the simulator's own "
            "noise-free waveform of the same points, read by the same algorithm: it checks "
            "the processing chain, not the measurement, so it is near zero by construction.",
        "R² (heights only)": "the squared correlation of the values and the reference "
            "values, 0 to 1, given for heights only (an elevation's R² reflects the "
            "terrain's relief) and for 10 footprints or more.",
        "bias": "mean of the residuals (value minus reference value): metres (cover: "
                "fraction).",
        "RMSE": "root mean square of the residuals: metres (cover: fraction).",
        "slope class": "terrain slope of the footprint in degrees (the plane through the "
                       "airborne ground points under it): 0-5, 5-10, 10-20, 20-30, >30 degrees.",
        "aspect class": "the compass direction the terrain of the footprint faces "
                        "(downhill), N to NW in 45 degree sectors; flat = slope below 2 "
                        "degrees.",
        "reference outside": "a footprint only partly covered by the airborne points: less "
            "than 90 % of its circle over cells holding airborne points (past the tiles' "
            "edge or over a data gap). Its reference values are computed from the part "
            "covered, but it is left out of the statistics.",
    },
}


def gedi_glossary_section(terms: Sequence[str], reference: str = "waveform"
                          ) -> ReportSection:
    """The glossary of a GEDI report: the words of the footprint reference the run used
    (``reference``: "waveform" or "points")."""
    words = {**GLOSSARY, **GEDI_GLOSSARY[""], **GEDI_GLOSSARY.get(reference, {})}
    return ReportSection("Glossary", [f"{k}: {words[k]}" for k in terms if k in words])


def glossary_section(terms: Sequence[str] | None = None) -> ReportSection:
    """The glossary at the end of a report (``terms``: those it uses; default all)."""
    keys = list(GLOSSARY) if terms is None else [t for t in terms if t in GLOSSARY]
    return ReportSection("Glossary", [f"{k}: {GLOSSARY[k]}" for k in keys])


def _fitted_tiles_seen(tiles: Sequence[Path | str]) -> list[str]:
    """The tiles of ``tiles`` the estimators or the sigma model were fitted on."""

    seen = set()
    for t in tiles:  # a loop over tiles: a header each
        name = Path(str(t)).name.split(".")[0]
        fitted = _fitted_by_content(t)
        if name in CALIBRATION_TILES or fitted is not None:
            seen.add(name if fitted is None or fitted == name else f"{name} (= {fitted})")
    return sorted(seen)


_CALIBRATION_HEADERS: dict[tuple[int, tuple[float, ...]], str] = {
    (531662, (885022.37, 629157.18, 885210.15, 629399.99)): "lasR_bcts_1",
    (823945, (885024.09, 629400.0, 885217.09, 629699.99)): "lasR_bcts_2",
}
"""The calibration tiles by their header's point count and extent (cm), so a renamed copy
(or one in a .vpc) is recognised; a tile given by URL is named only."""


def _fitted_by_content(tile: Path | str) -> str | None:
    """The calibration tile whose points ``tile`` holds (by its header), or None."""
    text = str(tile)
    if "://" in text or not text.lower().endswith((".las", ".laz")):
        return None
    try:
        import laspy

        with laspy.open(text) as reader:
            h = reader.header
            key = (int(h.point_count), tuple(round(float(v), 2) for v in
                                             (h.mins[0], h.mins[1], h.maxs[0], h.maxs[1])))
    except Exception:  # noqa: BLE001 -- unreadable here: its reader reports it
        return None
    return _CALIBRATION_HEADERS.get(key)


def training_caveat(tiles: Sequence[Path | str]) -> str:
    """The report's first caveat in one line for the terminal, when the tiles validated
    are those the estimators and the sigma model were fitted on (else "")."""
    seen = _fitted_tiles_seen(tiles)
    if not seen:
        return ""
    return (f"Read with care: the tiles validated here ({', '.join(seen)}) are the tiles the "
            "recommended estimators and the sigma model were fitted on; the report gives "
            "the errors measured on unseen tiles.")


def training_sentence(tiles: Sequence[Path | str]) -> str:
    """Which tiles the recommended estimators and the sigma model were fitted on; said
    first when the tiles under validation are among them, with the figures measured on
    tiles never used for fitting."""
    seen = _fitted_tiles_seen(tiles)
    base = ("The recommended estimators' windows and the per-block sigma model were fitted "
            f"on the tiles {', '.join(CALIBRATION_TILES)} (ICESat-2 tracks simulated over "
            "them, night and day, strong and weak beams).")
    if not seen:
        return base + (" The tiles validated here are not among them. Measured elsewhere on "
                       f"three tiles never used for fitting: {UNSEEN_FIGURES}.")
    return (f"Read these numbers with care: the tiles validated here ({', '.join(seen)}) are "
            "the very tiles the recommended estimators and the sigma model were fitted on, "
            "so the errors below are those of data the method was fitted on. " + base
            + f" Measured elsewhere, on three tiles never used for fitting: {UNSEEN_FIGURES}.")
