"""The one vocabulary of the front doors: every option's name, meaning, unit, default,
choices and help, declared once.

The command line (``cli/options.py`` turns an entry into a ``click.option``), the QGIS
algorithms (``qgis_plugin/algorithms/base.py`` turns one into a Processing parameter named
``keyword.upper()``) and the Python keyword of the same name all read this table, so a
name means one thing wherever it is spelled. tests/test_option_vocabulary.py walks every
command's options and every QGIS algorithm's parameters against it.

To add an option: add an :class:`Option` to :data:`OPTIONS` (its ``name`` the long option,
``keyword`` the Python keyword and parameter name), then use it with
``cli.options.option("--name")`` in the command and ``self.table_parameter("--name")`` in
the QGIS algorithm. A renamed option keeps its old spelling for a release: list it in
``cli/vocabulary.DEPRECATED_OPTIONS`` (and the CHANGELOG).

Only plain Python here: the table is read when ``--help`` is printed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["Option", "OPTIONS", "option_spec", "ESTIMATOR_PRESETS", "RECOMMENDED_PRESET",
           "PHOTON_RATES", "DEFAULT_PHOTON_RATE", "REFERENCE_STATISTICS", "Kind",
           "SURVEY_SOURCES_HELP"]

#: What an option's value is: a file or folder path, a number, one of named choices, an
#: on/off switch, a CRS (EPSG code, WKT or PROJ string), or free text.
Kind = Literal["file", "folder", "number", "choice", "switch", "crs", "text"]

#: What an airborne survey option (``--points``, ``--tiles``) accepts, said once: plain
#: LAS/LAZ tiles are read from local files only, COPC and EPT also by URL.
SURVEY_SOURCES_HELP = ("local LAS/LAZ tiles, a folder or glob pattern of them, or a .vpc; a "
                       "COPC or an ept.json, local or by URL (https://, s3://); repeatable")

#: The block estimator presets every front end offers, the recommended (the default) first.
#: ``blocks.estimators.PRESETS`` holds what each name computes and checks it names these.
ESTIMATOR_PRESETS: tuple[str, ...] = ("atl08", "paper", "icesat2", "mabel")
#: The estimator preset the project recommends, the default of every front end.
RECOMMENDED_PRESET: str = ESTIMATOR_PRESETS[0]

#: The ecosystem photon rates of a simulation (``simulate.params.POISSON_MEANS``).
PHOTON_RATES: tuple[str, ...] = ("boreal", "temperate", "tropical")
DEFAULT_PHOTON_RATE: str = "temperate"

#: How a block's footprint-matched reference is made from its footprints' airborne returns
#: (``reference.footprint_blocks``), the default first: ``pooled`` (the estimate's own
#: statistic of the returns pooled over the block: like with like), ``footprint-mean`` /
#: ``footprint-max`` (the mean / maximum over the footprints of each footprint's RH).
REFERENCE_STATISTICS: tuple[str, ...] = ("pooled", "footprint-mean", "footprint-max")


@dataclass(frozen=True)
class Option:
    """One option of the vocabulary.

    Parameters
    ----------
    name : str
        The long option, e.g. ``"--photon-rate"``.
    keyword : str
        The Python keyword (and QGIS parameter name, upper case) of the same meaning.
    meaning : str
        What the name means, in a few words: the same in every command.
    kind : Kind
        What the value is.
    help : str
        The help text (commands may add a sentence about their use of it).
    unit : str, optional
        The value's unit (``"m"``, ``"degrees"``, ``"MHz"``).
    default : object, optional
        The default (None: decided by the input, said in ``help``).
    choices : tuple of str, optional
        The allowed values of a ``choice``, the default first.
    multiple : bool
        Repeatable on the command line.
    qgis : str, optional
        The QGIS parameter name when it is not ``keyword.upper()``.
    """

    name: str
    keyword: str
    meaning: str
    kind: Kind
    help: str
    unit: str | None = None
    default: Any = None
    choices: tuple[str, ...] | None = None
    multiple: bool = False
    qgis: str | None = None

    @property
    def qgis_name(self) -> str:
        """The QGIS Processing parameter of this meaning."""
        return self.qgis or self.keyword.upper()


_PRESET_HELP = ("Block estimators: atl08 (the recommended: photons classified as ATL08 does; "
                "ground = its ground surface, Hmax = 98th percentile of the canopy heights "
                "above it), paper (the paper's method), icesat2 (density filter, the paper's "
                "ground window, 98th-percentile top), mabel (density filter, ground surface, "
                "98th-percentile top).")

_TABLE: tuple[Option, ...] = (
    Option("--preset", "preset", "block estimator preset", "choice", _PRESET_HELP,
           default=RECOMMENDED_PRESET, choices=ESTIMATOR_PRESETS),
    Option("--photon-rate", "photon_rate", "ecosystem photon rate of a simulation", "choice",
           "Simulated photon rate: Poisson mean photons per strong-beam shot, boreal 1.0, "
           "temperate 1.9, tropical 0.6.", default=DEFAULT_PHOTON_RATE, choices=PHOTON_RATES),
    Option("--length", "lengths", "block or segment length along the track", "number",
           "Block length, m; repeat for several.", unit="m", multiple=True),
    Option("--plot", "plot", "one figure (PNG file)", "file", "Write a figure (PNG).",
           qgis="PLOT"),
    Option("--k-sigma", "k_sigma", "a threshold in standard deviations", "number",
           "Noise filter threshold k, in standard deviations.", unit="standard deviations"),
    # three CRSs, three names: the output's, the airborne tiles', an input table's
    Option("--crs", "crs", "the CRS of the output x/y", "crs",
           "Metric CRS of the output x/y (default: the UTM zone of the track)."),
    Option("--points-crs", "points_crs", "the CRS of airborne tiles that state none", "crs",
           "CRS of airborne LAS/LAZ tiles that state none (e.g. EPSG:3005)."),
    Option("--table-crs", "table_crs", "the CRS of an input table that carries none", "crs",
           "CRS of the x/y of an input CSV table (CSV carries none)."),
    # photons: the input file, the simulated table, the labelled layer
    Option("--photons", "photons", "the input photon file", "file",
           "ATL03 / MABEL / table photon file.", qgis="INPUT"),
    Option("--photon-table", "photon_table", "also write the simulated photons as a table",
           "file", "Also write every realisation's photons with truth (.parquet/.gpkg/.csv)."),
    Option("--photon-layer", "with_photons", "also write the photon layer", "switch",
           "Also write layer 'photons' with per-photon labels (GeoPackage output).",
           qgis="PHOTONS"),
    Option("--channel", "channel", "MABEL channel", "text",
           "MABEL channel number, or 'most' (the default)."),
    # ATL08: as a reference, as photon classes
    Option("--atl08", "atl08", "the matching ATL08 file as a reference", "file",
           "Matching ATL08 file: validate against its land segments."),
    Option("--atl08-classes", "atl08_classes", "the matching ATL08 file's photon classes",
           "file", "Matching ATL08 file: adds its class of each photon to the photons layer, "
           "column 'classification' (0 noise, 1 ground, 2 canopy, 3 top of canopy; -1 "
           "not classed by ATL08)."),
    Option("--plots", "plots", "a folder of figures", "folder", "Folder for the figures (PNG)."),
    # shared settings
    Option("--width", "width", "corridor width", "number",
           "Corridor width, m (default: the footprint of the photons' sensor: ICESat-2 13, "
           "MABEL 2; a photon table of no known sensor needs it).", unit="m"),
    Option("--min-signal-conf", "min_signal_conf", "ATL03 signal confidence floor", "number",
           "ATL03: keep photons with land signal_conf_ph >= this before the noise filter."),
    Option("--search-range", "search_range", "co-registration search range", "number",
           "Search +- this many metres along and across the track.", unit="m", default=15.0),
    Option("--diameter", "diameter", "footprint diameter", "number",
           "Footprint diameter, m.", unit="m"),
    Option("--beam-strength", "beam_strength", "beam strength of a simulation", "choice",
           "The weak beam gets a quarter of the photons.", default="strong",
           choices=("strong", "weak")),
    Option("--photon-vcrs", "photon_vcrs", "vertical datum of the photon heights", "crs",
           "Vertical datum of the photon heights (ATL03/MABEL/GEDI: WGS84 ellipsoid)."),
    Option("--reference-vcrs", "reference_vcrs", "vertical datum of the reference", "crs",
           "Vertical/compound CRS of the reference heights."),
    Option("--reference-statistic", "reference_statistic",
           "how a block's footprint reference is made from its footprints", "choice",
           "Block footprint reference: pooled (the estimate's own statistic -- e.g. the 98th "
           "percentile of the canopy heights -- of the airborne returns pooled over the "
           "block's footprints), footprint-mean or footprint-max (the mean or maximum over "
           "the footprints of each footprint's RH of all returns).",
           default=REFERENCE_STATISTICS[0], choices=REFERENCE_STATISTICS),
    Option("--reference", "reference", "what blocks are judged against", "choice",
           "Reference for blocks: corridor rasters, ATL08, or the footprint-matched airborne "
           "points.", choices=("corridor", "atl08", "footprint")),
)

#: Every option of the vocabulary by its long name.
OPTIONS: dict[str, Option] = {o.name: o for o in _TABLE}


def option_spec(name: str) -> Option:
    """The table entry of option ``name`` (``"--photon-rate"``); KeyError names the table."""
    try:
        return OPTIONS[name]
    except KeyError:
        raise KeyError(f"{name} is not in canopyblocks.options.OPTIONS: add it there "
                       "first") from None
