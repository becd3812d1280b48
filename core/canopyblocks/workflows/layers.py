"""Workflows on layers already in memory: the entry points of the QGIS algorithms that take
a layer (blocks, residuals, footprints) rather than a file, and return the layers to show.

Each is one call for its algorithm; the choices (which reference, which estimators, which
corridor width) are made here or in the workflow it calls, never in the algorithm.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..progress import Progress, as_progress

if TYPE_CHECKING:
    import geopandas as gpd
    import pandas as pd

    from ..blocks import BlockParams

__all__ = ["BlockLayers", "block_layers", "validate_block_layer", "validate_footprint_layer",
           "aspect_statistics", "block_corridors", "waveform_views"]


@dataclass(frozen=True)
class BlockLayers:
    """What :func:`block_layers` made: ``blocks``, the ``track`` read, the per-photon
    ``labels`` by block length (when asked), the ``photons`` layer and ATL08-style
    ``segments`` (when asked), the ``profile`` PNG written (or None)."""

    blocks: Any
    track: Any
    labels: dict[float, Any] | None = None
    photons: Any = None
    segments: Any = None
    profile: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def block_layers(path: str | os.PathLike[str], params: BlockParams, *,
                 preset: str | None = None, track: dict[str, Any] | None = None,
                 calibration: str | os.PathLike[str] | None = None,
                 photon_layer: bool = False, segment_length: float | None = None,
                 profile: str | os.PathLike[str] | None = None,
                 progress: Progress | None = None) -> BlockLayers:
    """One photon track (``track``: ``beam``/``channel``/``crs``/``atl08`` keywords of
    :func:`~canopyblocks.readers.open_track`) -> its block layer with the estimators of
    ``preset`` (default the recommended), optionally the photon layer, the ATL08-style
    segments of ``segment_length`` metres and the profile plot at ``profile``."""
    from ..blocks.estimators import preset as named_preset
    from ..readers import open_track
    from .blocks import calibrate_blocks, run_blocks, track_strengths
    from .blocks import photon_layer as make_photon_layer

    prog = as_progress(progress)
    t = open_track(path, progress=prog.sub(0.0, 0.2), **(track or {}))
    prog.update(0.2, f"{len(t)} photons read")
    want_labels = photon_layer or profile is not None
    est = named_preset(preset) if preset is not None else named_preset()
    blocks, all_labels = run_blocks([t], params, labels=want_labels, estimators=est,
                                    progress=prog.sub(0.2, 0.85))
    labels = all_labels.get(t.track) if want_labels else None
    if calibration:
        blocks = calibrate_blocks(blocks, calibration, track_strengths(path, [t]))
    photons = make_photon_layer([t], {t.track: labels}) \
        if photon_layer and labels is not None else None
    segments = None
    if segment_length is not None:
        from ..blocks.atl08_classify import classify_photons
        from ..blocks.atl08_segments import atl08_segments

        segments = atl08_segments(t, classify_photons(t), segment_length, params.s0)
    prog.update(0.95, "computed")
    if profile is not None:
        from ..outputs.profile_plot import plot_profile

        plot_profile(t, blocks, profile, labels=labels)
    return BlockLayers(blocks, t, labels, photons, segments,
                       None if profile is None else str(profile))


def validate_block_layer(blocks: gpd.GeoDataFrame, *, reference: str | None = None,
                         dtm: Any = None, dsm_max: Any = None, dsm_p90: Any = None,
                         points: Sequence[str] = (), diameter: float | None = None,
                         width: float | None = None, slope_threshold: float = 2.0,
                         progress: Progress | None = None, **vertical: Any) -> Any:
    """A block layer validated against the corridor rasters or the footprint-matched
    airborne points: ``reference`` ``"corridor"``/``"footprint"``, default (None) as
    ``validate``: the footprint reference when ``points`` are given without a ``dtm``.
    ``vertical``: ``offset``, ``geoid``, ``photon_vertical_crs``. Returns the result with
    ``residuals`` and ``stats``."""
    if reference is None:
        reference = "footprint" if points and dtm is None else "corridor"
    if reference == "footprint":
        from ..reference.footprint_params import FootprintReferenceParams
        from ..validation.footprints import validate_blocks_footprint

        if not points:
            raise InputError("the footprint-matched reference needs the airborne LAS/LAZ "
                             "tiles")
        params = FootprintReferenceParams(diameter=diameter) if diameter is not None \
            else FootprintReferenceParams()
        return validate_blocks_footprint(blocks, [str(p) for p in points], params=params,
                                         slope_threshold=slope_threshold, progress=progress,
                                         **vertical)
    missing = [n for n, v in (("DTM", dtm), ("DSM (maximum)", dsm_max),
                              ("DSM (90th percentile)", dsm_p90)) if v in (None, "")]
    if missing:
        raise InputError("the raster reference needs the DTM, DSM (maximum) and DSM (90th "
                         f"percentile); missing: {', '.join(missing)}")
    from ..validation.block_validation import validate_blocks

    return validate_blocks(blocks, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90, width=width,
                           slope_threshold=slope_threshold, progress=progress, **vertical)


def validate_footprint_layer(footprints: gpd.GeoDataFrame, points: Sequence[str], *,
                             diameter: float, progress: Progress | None = None,
                             **vertical: Any) -> Any:
    """Waveform footprints against the command line's GEDI footprint reference of
    ``diameter`` metres (formed as the waveform is); returns the result with ``residuals``
    and ``stats``."""
    from ..reference.footprint_params import FootprintReferenceParams
    from ..validation.footprints import validate_footprints

    return validate_footprints(footprints, list(points),
                               params=FootprintReferenceParams.gedi(diameter=diameter),
                               progress=progress, **vertical)


def aspect_statistics(residuals: pd.DataFrame, groups: Any
                      ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Statistics of a residuals layer per class (``groups`` as
    :func:`~canopyblocks.validation.stats.block_stats`) and the rows they use (``use``
    as stored by a layer: 0/1 or NULL, read as a bool)."""
    from ..blocks.uncertainty import upgrade_table
    from ..validation.stats import block_stats

    upgrade_table(residuals)  # a layer stores booleans as 0/1 or NULL; older ones lack use
    stats = block_stats(residuals, groups=groups)
    used = residuals[residuals["use"]] if "use" in residuals.columns else residuals
    return stats, used


def block_corridors(blocks: gpd.GeoDataFrame, width: float | None = None) -> gpd.GeoDataFrame:
    """The corridor polygon of every block (``width`` m; default the photons' footprint)."""
    from ..reference.corridor import block_corridors as corridors

    return corridors(blocks, width=width)


def waveform_views(path: str | os.PathLike[str], shots: Iterable[int],
                   output: str | os.PathLike[str], *, setting: str = "a1",
                   progress: Progress | None = None) -> tuple[Path, list[str]]:
    """The waveforms of ``shots`` in a GEDI L1B file processed with L2A ``setting``: one PNG
    per shot beside ``output`` (``<stem>_<shot>.png``) and the HTML view at ``output``."""
    from ..outputs.waveform_plot import plot_waveform, waveform_html
    from ..readers.gedi import iter_gedi_l1b
    from ..waveforms.process import shot_details
    from ..waveforms.settings import WaveformParams

    wanted = {int(s) for s in shots}
    params = WaveformParams(setting=setting)  # type: ignore[arg-type]
    details = []
    for batch in iter_gedi_l1b(path, progress=as_progress(progress).sub(0.0, 0.8)):
        sn = batch.shot_number.astype("int64")
        details += [shot_details(batch, i, params) for i, s in enumerate(sn) if int(s) in wanted]
    missing = wanted - {d.shot_number for d in details}
    if missing:
        raise InputError(f"shot(s) {', '.join(map(str, sorted(missing)))} are not in {path}")
    out = Path(output)
    pngs = []
    for d in details:
        png = out.with_name(f"{out.stem}_{d.shot_number}.png")
        plot_waveform(d, png)
        pngs.append(str(png))
    waveform_html(details, out)
    return out, pngs
