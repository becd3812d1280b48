"""Column names, flags and layer names of the output contract (DESIGN.md section 5).

Scripts and the QGIS layers rely on these names; change them only with a major version.
"""

from __future__ import annotations

__all__ = [
    "BLOCK_COLUMNS",
    "REFERENCE_COLUMNS",
    "RESIDUAL_COLUMNS",
    "TERRAIN_COLUMNS",
    "STATS_COLUMNS",
    "METRICS",
    "FLAG_OK",
    "FLAG_SPARSE",
    "FLAG_INVERTED",
    "FLAG_IMPLAUSIBLE",
    "MAX_CANOPY_HEIGHT_M",
    "FLAG_LOW_CONFIDENCE",
    "FLAGS",
    "LAYER_BLOCKS",
    "LAYER_RESIDUALS",
    "LAYER_STATS",
    "LAYER_PHOTONS",
    "LAYER_CORRIDOR",
    "LAYER_FOOTPRINTS",
    "FOOTPRINT_COLUMNS",
    "FOOTPRINT_FLAGS",
    "LABEL_NOISE",
    "LABEL_GROUND",
    "LABEL_CANOPY",
    "LABEL_BETWEEN",
    "LABEL_NAMES",
]

#: Block table columns, in order (plus the point ``geometry`` at the block centre).
BLOCK_COLUMNS: tuple[str, ...] = (
    "track",      # beam or channel id
    "length",     # block length, m
    "block",      # integer index counted from s0
    "s_start",    # along-track start of the block, m
    "s_end",      # along-track end, m
    "x",          # block centre, track CRS, m
    "y",
    "lon",        # block centre, degrees WGS84
    "lat",
    "n_photons",  # photons in the block
    "n_kept",     # after the noise filter
    "n_between",  # kept photons with ground <= z <= top
    "top",        # canopy top, m (input vertical datum)
    "ground",     # mean ground, m
    "hmax",       # top - ground, m
    "z90",        # 90th percentile height of the photons between ground and top, m
    "h90",        # z90 - ground, m
    "flag",       # ok / sparse / inverted / implausible / low_confidence
    "hmax_sigma",    # 1-sigma error of hmax, m (atl08 preset; NaN where not modelled)
    "ground_sigma",  # 1-sigma error of ground, m (atl08 preset; NaN where not modelled)
    "use",        # bool: enters headline statistics (flag ok)
)

FLAG_OK = "ok"
FLAG_SPARSE = "sparse"
FLAG_INVERTED = "inverted"
FLAG_IMPLAUSIBLE = "implausible"  # Hmax taller than any tree (blocks/plausibility.py)

#: The canopy ceiling, m: no tree is taller (the tallest measured, a redwood, is about
#: 116 m). Blocks above it are flagged implausible (blocks/plausibility.py), GEDI
#: footprints above it terrain outliers (waveforms/gedi_outliers.py).
MAX_CANOPY_HEIGHT_M = 130.0
FLAG_LOW_CONFIDENCE = "low_confidence"  # sigma too wide to be useful (blocks/uncertainty.py)
FLAGS: tuple[str, ...] = (FLAG_OK, FLAG_SPARSE, FLAG_INVERTED, FLAG_IMPLAUSIBLE,
                          FLAG_LOW_CONFIDENCE)

#: The four validated metrics, photon-side column -> reference-side column.
METRICS: tuple[str, ...] = ("ground", "top", "hmax", "h90")

REFERENCE_COLUMNS: tuple[str, ...] = ("ref_ground", "ref_top", "ref_top90", "ref_hmax", "ref_h90")
TERRAIN_COLUMNS: tuple[str, ...] = ("slope", "aspect", "aspect_class")
RESIDUAL_COLUMNS: tuple[str, ...] = (
    *REFERENCE_COLUMNS,
    "res_ground",
    "res_top",
    "res_hmax",
    "res_h90",
    *TERRAIN_COLUMNS,
    "coverage",
)
STATS_COLUMNS: tuple[str, ...] = (
    "length", "metric", "group", "n", "bias", "rmse", "mae", "slope", "intercept", "r2",
)

LAYER_BLOCKS = "blocks"
LAYER_RESIDUALS = "residuals"
LAYER_STATS = "stats"
LAYER_PHOTONS = "photons"
LAYER_CORRIDOR = "corridor"
LAYER_FOOTPRINTS = "footprints"

#: Footprint table columns (waveforms, DESIGN section 5), in order (plus the point
#: ``geometry`` at the footprint's position at the ground elevation, in a metric CRS).
FOOTPRINT_COLUMNS: tuple[str, ...] = (
    "beam",         # e.g. BEAM0101
    "shot_number",  # int64, exact
    "time",         # delta_time, s
    "lon",          # degrees WGS84, at the ground
    "lat",
    "ground",       # m, elevation of the lowest mode (L2A elev_lowestmode)
    "top",          # m, elevation of the signal top (L2A elev_highestreturn)
    "rh25", "rh50", "rh75", "rh90", "rh95", "rh98", "rh100",  # m above ground
    "cover",        # canopy cover fraction 0..1
    "penetration",  # share of the energy within 2 m above the ground
    "n_modes",      # modes detected
    "setting",      # a1..a6
    "flag",         # see FOOTPRINT_FLAGS
)
FOOTPRINT_FLAGS: tuple[str, ...] = (
    "ok", "no_signal", "too_many_modes", "degraded", "stale", "terrain_outlier",
    "invalid_shot",  # impossible L1B values (bin spacing, sample pool, amplitude, position):
                     # heights and position not given (readers/gedi_geometry.py)
    "no_ground",     # dual-wavelength pairs: no single ground edge found
)

#: Per-photon labels (``compute_blocks(..., labels=True)``).
LABEL_NOISE = 0      # removed by the noise filter (or by the signal-confidence threshold)
LABEL_GROUND = 1     # kept, in the final ground window
LABEL_CANOPY = 2     # kept, in the final canopy-top window
LABEL_BETWEEN = 3    # kept, in neither window
LABEL_NAMES = {LABEL_NOISE: "noise", LABEL_GROUND: "ground", LABEL_CANOPY: "canopy",
               LABEL_BETWEEN: "between"}
