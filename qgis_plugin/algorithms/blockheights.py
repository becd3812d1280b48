"""``canopyblocks:blockheights``: photon file -> canopy top, ground, Hmax, H90 per block."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterCrs,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import pyproj_crs, write_frame
from ..styles import style_on_load
from .base import (
    SEED_001,
    CanopyBlocksAlgorithm,
    input_label,
    optional_number,
    parse_lengths,
    table_choices,
)

__all__ = ["BlockHeightsAlgorithm"]

NOISE_OPTIONS = ("sigma", "none")
#: What each estimator preset computes, in the dialog's words (the names, their order and
#: the default come from the core's one vocabulary: ``canopyblocks.options``)
PRESET_LABELS = {
    "atl08": "atl08 (recommended): photons classified as ATL08 does, its ground surface, "
             "98th percentile of the canopy heights",
    "paper": "paper: the paper's method (k-sigma noise filter, top and ground windows)",
    "icesat2": "icesat2: density noise filter, the paper's ground window, 98th-percentile top",
    "mabel": "mabel: density noise filter, ground surface, 98th-percentile top",
}


def preset_options() -> tuple[tuple[tuple[str, str], ...], int]:
    """((menu label, preset name), ...) in the core's order, and the default's index."""
    names, default = table_choices("--preset")
    return tuple((PRESET_LABELS.get(n, n), n) for n in names), default


def parse_track(text: str) -> dict[str, Any]:
    """``"gt1r"`` -> beam; ``"49"``/``"most"`` -> MABEL channel; ``""`` -> reader default."""
    t = (text or "").strip()
    if not t:
        return {}
    if t.lower() == "most":
        return {"channel": "most"}
    if t.isdigit():
        return {"channel": int(t)}
    return {"beam": t.lower()}


class BlockHeightsAlgorithm(CanopyBlocksAlgorithm):
    """Block canopy heights from one ATL03 beam, MABEL channel or photon table."""

    ALG_ID = "blockheights"
    DISPLAY = "Block canopy heights from photons"
    HELP = (
        "Cuts one photon track (an ATL03 beam, a MABEL channel, or a photon table) into "
        "along-track blocks of the given lengths and computes per block the canopy top, the "
        "mean ground, Hmax = top - ground and H90. <b>Estimators</b>: by default (atl08, "
        "recommended) the photons are classified as ATL08 does; ground = its ground surface, "
        "Hmax = 98th percentile of the canopy heights above it. 'paper' is the paper's "
        "method: the expansion-window method on 0.5 m height histograms after a per-block "
        "k-sigma noise filter (" + SEED_001 + "; cut-offs by block length, top/ground: 50 m "
        "10 %/25 %, 25 m 10 %/20 %, 10 m 5 %/7.5 %; other lengths interpolated; the noise "
        "filter and cut-off settings below apply to it).<br><br>"
        "<b>Photon file</b>: ATL03 HDF5, MABEL HDF5 or a table (CSV/Parquet).<br>"
        "<b>Beam or channel</b>: gt1l..gt3r for ATL03, a channel number or 'most' for MABEL; "
        "empty = the reader's default.<br>"
        "<b>Block lengths</b>: metres, comma separated (e.g. '25, 10').<br>"
        "Outputs: block points (track CRS, UTM by default) with fields track, length, block, "
        "s_start, s_end, x, y, lon, lat, n_photons, n_kept, n_between, top, ground, hmax, z90, "
        "h90, flag (ok / sparse / inverted / implausible: Hmax above 130 m, taller than any "
        "tree); optionally the photons with their labels per block length (text: 'noise', "
        "'ground', 'canopy', 'between', 'outside'; with the atl08 estimators also "
        "classed_pc_flag: 0 noise, 1 ground, 2 canopy, 3 top of canopy) and a profile PNG. "
        "Optionally ATL08-style segments of the given length (100 m like ATL08) from photons "
        "classified as ATL08 does, with ATL08's field names: h_te_mean, h_te_median, "
        "h_te_best_fit, h_canopy (98th percentile of the canopy heights), h_mean_canopy, "
        "canopy_h_metrics_10..95, canopy_openness, n_te_photons, n_ca_photons, "
        "n_toc_photons. "
        "Heights are in the input's vertical datum (ellipsoidal for ATL03/MABEL)."
    )

    INPUT = "INPUT"
    TRACK = "TRACK"
    LENGTHS = "LENGTHS"
    S0 = "S0"
    K_SIGMA = "K_SIGMA"
    NOISE = "NOISE"
    TOP_CUTOFF = "TOP_CUTOFF"
    GROUND_CUTOFF = "GROUND_CUTOFF"
    MIN_PHOTONS = "MIN_PHOTONS"
    MIN_SIGNAL_CONF = "MIN_SIGNAL_CONF"
    ATL08 = "ATL08"
    OUTPUT = "OUTPUT"
    PHOTONS = "PHOTONS"
    CRS = "CRS"
    PRESET = "PRESET"
    CALIBRATION = "CALIBRATION"
    PROFILE = "PROFILE"
    SEGMENTS = "SEGMENTS"
    SEGMENT_LENGTH = "SEGMENT_LENGTH"
    ADVANCED = (S0, NOISE, K_SIGMA, TOP_CUTOFF, GROUND_CUTOFF, MIN_PHOTONS, MIN_SIGNAL_CONF,
                ATL08, CALIBRATION, CRS, SEGMENT_LENGTH)

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.add_photon_parameters(default_lengths="25")
        self.addParameter(QgsProcessingParameterNumber(
            self.S0, "Block origin along track s0 (m; empty = track start)",
            type=QgsProcessingParameterNumber.Double, optional=True))
        self.addParameter(QgsProcessingParameterEnum(
            self.NOISE, "Noise filter", options=["k-sigma per block (paper)", "none"],
            defaultValue=0))
        self.addParameter(QgsProcessingParameterNumber(
            self.K_SIGMA, "Noise filter k (standard deviations)",
            type=QgsProcessingParameterNumber.Double, defaultValue=2.5, minValue=0.01))
        self.addParameter(QgsProcessingParameterNumber(
            self.TOP_CUTOFF, "Canopy-top cut-off fraction (empty = paper default by length)",
            type=QgsProcessingParameterNumber.Double, optional=True,
            minValue=0.0, maxValue=1.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.GROUND_CUTOFF, "Ground cut-off fraction (empty = paper default by length)",
            type=QgsProcessingParameterNumber.Double, optional=True,
            minValue=0.0, maxValue=1.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.MIN_PHOTONS, "Minimum kept photons per block (else flagged sparse)",
            type=QgsProcessingParameterNumber.Integer, defaultValue=10, minValue=1))
        self.add_signal_conf_parameter()
        self.addParameter(QgsProcessingParameterFile(
            self.ATL08, "Matching ATL08 file (adds photon classes)",
            behavior=QgsProcessingParameterFile.File, optional=True,
            fileFilter="HDF5 (*.h5 *.hdf5);;All files (*.*)"))
        presets, default = preset_options()
        self.addParameter(QgsProcessingParameterEnum(
            self.PRESET, "Estimators", options=[label for label, _ in presets],
            defaultValue=default))
        self.addParameter(QgsProcessingParameterFile(
            self.CALIBRATION, "Bias calibration (JSON from Calibrate, bias method)",
            behavior=QgsProcessingParameterFile.File, fileFilter="Calibration (*.json)",
            optional=True))
        self.addParameter(QgsProcessingParameterCrs(
            self.CRS, "Output CRS (metric; empty = the UTM zone of the track)",
            optional=True))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Blocks", type=QgsProcessing.TypeVectorPoint))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.PHOTONS, "Photons with labels", type=QgsProcessing.TypeVectorPoint,
            optional=True, createByDefault=False))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.PROFILE, "Profile plot", fileFilter="PNG (*.png)", optional=True,
            createByDefault=False))
        self.addParameter(QgsProcessingParameterNumber(
            self.SEGMENT_LENGTH, "ATL08-style segment length (m)",
            type=QgsProcessingParameterNumber.Double, defaultValue=100.0, minValue=0.001))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.SEGMENTS, "ATL08-style segments", type=QgsProcessing.TypeVectorPoint,
            optional=True, createByDefault=False))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        params_mod = import_core("canopyblocks.workflows.params")
        layers = import_core("canopyblocks.workflows.layers")
        path = self.parameterAsFile(parameters, self.INPUT, context)
        track_kw = parse_track(self.parameterAsString(parameters, self.TRACK, context))
        lengths = parse_lengths(self.parameterAsString(parameters, self.LENGTHS, context))
        params = params_mod.BlockParams(
            lengths=lengths,
            s0=optional_number(self, parameters, self.S0, context),
            k_sigma=self.parameterAsDouble(parameters, self.K_SIGMA, context),
            noise=NOISE_OPTIONS[self.parameterAsEnum(parameters, self.NOISE, context)],
            top_cutoff=optional_number(self, parameters, self.TOP_CUTOFF, context),
            ground_cutoff=optional_number(self, parameters, self.GROUND_CUTOFF, context),
            min_photons=self.parameterAsInt(parameters, self.MIN_PHOTONS, context),
            min_signal_conf=self.min_signal_conf(parameters, context),
        )
        qcrs = self.parameterAsCrs(parameters, self.CRS, context)
        if qcrs.isValid():  # metric CRS of x/y and of the output layers
            track_kw["crs"] = pyproj_crs(qcrs)
        atl08 = self.parameterAsFile(parameters, self.ATL08, context) or None
        if atl08:
            track_kw["atl08"] = atl08
        profile = self.parameterAsFileOutput(parameters, self.PROFILE, context) \
            if parameters.get(self.PROFILE) is not None else ""
        feedback.pushInfo(f"reading {path} {track_kw or ''}")
        made = layers.block_layers(
            path, params,
            preset=preset_options()[0][self.parameterAsEnum(parameters, self.PRESET,
                                                            context)][1],
            track=track_kw,
            calibration=self.parameterAsFile(parameters, self.CALIBRATION, context) or None,
            photon_layer=parameters.get(self.PHOTONS) is not None,
            segment_length=self.parameterAsDouble(parameters, self.SEGMENT_LENGTH, context)
            if parameters.get(self.SEGMENTS) is not None else None,
            profile=profile or None, progress=progress)
        blocks, track, labels = made.blocks, made.track, made.labels
        feedback.pushInfo(
            f"{len(blocks)} blocks, {int((blocks['flag'] == 'ok').sum())} flagged ok")
        results: dict[str, Any] = {}
        dest = write_frame(self, parameters, self.OUTPUT, context, blocks, feedback)
        results[self.OUTPUT] = dest
        lengths_text = ", ".join(f"{v:g}" for v in lengths) + " m"
        source = input_label(path, str(track.track), lengths_text)
        style_on_load(context, dest, "height", "hmax", name=f"Blocks - {source}")
        if made.photons is not None and labels is not None:
            pdest = write_frame(self, parameters, self.PHOTONS, context, made.photons,
                                feedback)
            results[self.PHOTONS] = pdest
            style_on_load(context, pdest, "label", f"label_{min(labels):g}m",
                          name=f"Photons with labels - {source}")
        if made.segments is not None:
            results[self.SEGMENTS] = write_frame(self, parameters, self.SEGMENTS, context,
                                                 made.segments, feedback)
        if profile:
            results[self.PROFILE] = profile
        if feedback.isCanceled():
            raise QgsProcessingException("cancelled by the user")
        return results
