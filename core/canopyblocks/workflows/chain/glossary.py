"""Plain words for the chain's reports: the glossary section at the end, and the
sentence saying which tiles fitted the estimators and the sigma model.

Every term a report uses that a user cannot look up is explained here in one line;
a report lists the terms it uses (:func:`glossary_section`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ...outputs.report import ReportSection

__all__ = ["GLOSSARY", "glossary_section", "training_sentence", "CALIBRATION_TILES",
           "UNSEEN_FIGURES"]

#: The tiles the recommended estimators' windows and the per-block sigma model were
#: fitted on (the package's ``blocks/uncertainty_model.json`` names them too).
CALIBRATION_TILES: tuple[str, ...] = ("lasR_bcts_1", "lasR_bcts_2")

#: What the recommended estimators (with a bias calibration) and their sigma scored on
#: three airborne tiles never used for fitting (lidR_Topography, pyfor_test,
#: lidR_MixedConifer), simulated night and day, 25 m blocks: the project's accuracy and
#: block-sigma benchmarks (measured elsewhere, not on this run).
UNSEEN_FIGURES = (
    "Hmax RMSE against the footprint-matched reference 1.9 m (strong beams, night) to "
    "3.0 m (strong, day) and 4.6 to 8.6 m (weak beams); ground RMSE 0.8 to 1.1 m "
    "(strong beams); the predicted sigma held for about 80 % of the Hmax residuals "
    "within 1 sigma and 96 % within 2 sigma")

#: term -> one line.
GLOSSARY: dict[str, str] = {
    "block": "a stretch of the track of the stated length (10, 25, 50 m ...); its heights "
             "come from the photons inside it.",
    "Hmax": "canopy height of a block: canopy top minus ground, metres.",
    "RH98": "relative height 98: the height above the ground below which 98 % of the "
            "return energy (or of the airborne points, weighted as the footprint) lies.",
    "footprint-matched airborne reference": "the airborne points seen as the sensor sees "
            "them: footprints of the sensor's size placed along the block, their ground "
            "and RH98 computed from the points weighted by the footprint; the like-with-like "
            "reference.",
    "corridor maximum": "the highest DSM cell and the mean DTM cell of the corridor (the "
            "cells a strip of the corridor width along the block touches): the paper's "
            "reference; it sits above what sparse photons can see.",
    "bias": "mean of the residuals (value minus reference value), metres.",
    "RMSE": "root mean square of the residuals, metres.",
    "95 % interval": "the range that holds the true bias (or RMSE) with 95 % confidence: "
            "bootstrap over the blocks or footprints (2,000 resamples, with replacement, from "
            "a fixed random state so the same data give the same interval), or the "
            "analytic interval above 5,000 blocks.",
    "R²": "the squared correlation of the values and the reference values (of the "
          "least-squares line), 0 to 1.",
    "sigma (hmax_sigma, ground_sigma)": "the predicted 1-sigma error of a block's Hmax or "
            "ground, metres, from the block's photon counts, noise and terrain.",
    "low_confidence": "a block whose predicted sigma is too wide to be useful; written, "
            "but left out of the statistics.",
    "sparse": "a block with too few photons for a height; written with no value.",
    "reference outside": "a block whose corridor or footprints are not covered by the "
            "airborne tiles; it has no reference value.",
    "implausible": "a block whose canopy height is taller than any tree.",
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
}


def glossary_section(terms: Sequence[str] | None = None) -> ReportSection:
    """The glossary at the end of a report (``terms``: those it uses; default all)."""
    keys = list(GLOSSARY) if terms is None else [t for t in terms if t in GLOSSARY]
    return ReportSection("Glossary", [f"{k}: {GLOSSARY[k]}" for k in keys])


def training_sentence(tiles: Sequence[Path | str]) -> str:
    """Which tiles the recommended estimators and the sigma model were fitted on; said
    first when the tiles under validation are among them, with the figures measured on
    tiles never used for fitting."""
    import importlib

    fitted_on = ""
    try:
        fitted_on = importlib.import_module("canopyblocks.blocks.uncertainty") \
            .sigma_model().fitted_on
    except Exception:  # noqa: BLE001 -- no model: name the tiles from the constant
        fitted_on = ""
    names = {Path(str(t)).name.split(".")[0] for t in tiles}
    seen = sorted(n for n in names if n in CALIBRATION_TILES or (fitted_on and n in fitted_on))
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
