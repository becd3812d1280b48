"""Make the bad-input corpus of issue 10 from the real files in ``tests/data``, at test time.

Each :class:`Case` writes one damaged input (or picks a bad parameter) into a folder of
its own and names the runner that feeds it to canopyblocks
(``tests/test_bad_input_corpus.py``).  The damage is derived from the real samples:

* ATL03 (``icesat2/vegr_atl03_clip.h5`` gt1r, ``icesat2/harmony_ATL03_gt1l.h5`` gt1l):
  truncations at many offsets, bit flips, deleted / renamed / reshaped / retyped
  datasets, NaN, +-inf and fill values (with and without ``_FillValue``) in every numeric
  dataset the reader uses, empty beams, a single photon;
* ATL08 (``icesat2/vegr_atl08_clip.h5``): truncations, missing datasets, invalid classes,
  fill values, a foreign granule;
* LAS/LAZ (``als/lidR_MixedConifer.laz``, ``als/lidR_Topography.laz``): truncations of
  the LAZ and of an uncompressed copy, lying headers (point counts, bounds, NaN / 1e300
  bounds, zero / negative / NaN scales, offsets, formats), missing / foot / geographic
  CRSs, all-noise, unclassified and height-normalised tiles, one point;
* reference GeoTIFFs (built here from the Topography points with numpy): undeclared
  nodata (-9999, float32 max, NaN), all zeros, other grids, other / missing CRSs, feet,
  integer and multi-band files, truncations and bit flips;
* photon tables, and bad parameters of the API and the command line.

Everything is seeded: the corpus is the same on every run.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .base import Base
from .damage import (
    F32_MAX,
    bit_flipped,
    delete,
    empty_beam_group,
    h5_edited,
    keep_photons,
    patched,
    rename,
    reshape,
    set_values,
    shift,
    truncated,
    write_cloud,
    write_cloud_geokeys,
)

Inputs = dict[str, Any]


@dataclass(frozen=True)
class Case:
    """One corpus case.

    Attributes
    ----------
    id : str
        Unique, readable test id.
    runner : str
        Name of the runner in the test module (``atl03``, ``las``, ``simulate`` ...).
    make : callable
        ``make(folder, base) -> inputs``: writes the damaged input into ``folder``;
        ``inputs["path"]`` is the damaged file (or None), other keys are runner options.
    needles : tuple of str
        A refusal must contain at least one of these (case-insensitive) besides the
        file's name; empty means any message naming the file.
    forbidden : tuple of str
        Misleading phrases a refusal must not contain.
    warn_words : tuple of str
        An accepted result must come with a warning containing one of these.
    must_refuse : bool
        Only a refusal is right (e.g. the input cannot be checked independently).
    must_accept : bool
        An undamaged input: it must be accepted and pass the independent check (this
        proves the checks right on real data).
    pdal : bool
        Runs PDAL.
    """

    id: str
    runner: str
    make: Callable[[Path, Base], Inputs]
    needles: tuple[str, ...] = ()
    forbidden: tuple[str, ...] = ()
    warn_words: tuple[str, ...] = ()
    must_refuse: bool = False
    must_accept: bool = False
    pdal: bool = False
    opts: dict[str, Any] = field(default_factory=dict)


# ---- case lists ----------------------------------------------------------------------------------

ATL03_FLOATS = ("heights/h_ph", "heights/lat_ph", "heights/lon_ph", "heights/dist_ph_along",
                "heights/delta_time", "geolocation/segment_dist_x")
ATL03_INTS = ("geolocation/segment_id", "geolocation/ph_index_beg",
              "geolocation/segment_ph_cnt", "heights/signal_conf_ph")
ATL03_USED = ATL03_FLOATS + ATL03_INTS + ("geolocation/segment_length",
                                          "geolocation/reference_photon_lat")
TRUNCATION_FRACTIONS = (0.0, 0.0005, 0.002, 0.01, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7,
                        0.8, 0.9, 0.95, 0.99, 0.999)
BROKEN_WORDS = ("truncat", "corrupt", "damaged", "not a", "not an", "cannot read", "unreadable",
                "incomplete", "invalid", "not hdf5", "not recognised", "not recognized",
                "no such", "missing", "lacks", "empty", "no gt", "not readable", "signature")


def _atl03_sources(base: Base) -> dict[str, tuple[Path, str, int | None]]:
    return {"vegr": (base.vegr, "gt1r", 2), "harmony": (base.harmony, "gt1l", None)}


def _atl03(src: str, fname: str, edit: Callable[[Path, Path], Path]
           ) -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        path, beam, msc = _atl03_sources(base)[src]
        out = edit(path, folder / fname)
        return {"path": out, "beam": beam, "min_signal_conf": msc}

    return make


def atl03_cases() -> list[Case]:
    cases: list[Case] = []
    for src in ("vegr", "harmony"):
        # truncations
        for frac in TRUNCATION_FRACTIONS:
            def edit(p: Path, d: Path, frac: float = frac) -> Path:
                return truncated(p, d, int(p.stat().st_size * frac))
            cases.append(Case(f"atl03-{src}-truncated-{frac:g}", "atl03",
                              _atl03(src, f"{src}_trunc.h5", edit), needles=BROKEN_WORDS,
                              forbidden=("no usable photons",)))
        for n in (8, 96, 700):
            def edit_n(p: Path, d: Path, n: int = n) -> Path:
                return truncated(p, d, n)
            cases.append(Case(f"atl03-{src}-truncated-{n}B", "atl03",
                              _atl03(src, f"{src}_trunc.h5", edit_n), needles=BROKEN_WORDS))
        # bit flips: some in the first 4 KiB (superblock, root objects), some anywhere
        rng = np.random.default_rng(7 if src == "vegr" else 8)
        for i in range(6):
            pos = [int(v) for v in rng.integers(0, 4096, size=3)]

            def edit_b(p: Path, d: Path, pos: list[int] = pos) -> Path:
                return bit_flipped(p, d, pos)
            cases.append(Case(f"atl03-{src}-bitflip-head-{i}", "atl03",
                              _atl03(src, f"{src}_flip.h5", edit_b)))
        for i in range(6):
            frac = float(rng.uniform(0.02, 0.98))

            def edit_b2(p: Path, d: Path, frac: float = frac, i: int = i) -> Path:
                size = p.stat().st_size
                r = np.random.default_rng(100 + i)
                return bit_flipped(p, d, [int(frac * size) + int(v)
                                          for v in r.integers(0, 64, 8)])
            cases.append(Case(f"atl03-{src}-bitflip-body-{i}", "atl03",
                              _atl03(src, f"{src}_flip.h5", edit_b2)))
    # dataset-level damage (both files for the core set, vegr for the rest)
    for src in ("vegr", "harmony"):
        beam = "gt1r" if src == "vegr" else "gt1l"

        def h5(edit_fn: Callable[[h5py.File], None], src: str = src
               ) -> Callable[[Path, Base], Inputs]:
            return _atl03(src, f"{src}_edit.h5",
                          lambda p, d, e=edit_fn: h5_edited(p, d, e))

        names = ATL03_USED if src == "vegr" else ATL03_FLOATS + ATL03_INTS[:3]
        for ds in names:
            short = ds.split("/")[-1]
            full = f"{beam}/{ds}"
            optional = short in ("segment_length", "reference_photon_lat") or (
                short == "signal_conf_ph" and src == "harmony")
            cases.append(Case(f"atl03-{src}-deleted-{short}", "atl03", h5(delete(full)),
                              needles=(short,) if not optional else (),
                              forbidden=("no usable photons",)))
            if src == "vegr":
                cases.append(Case(f"atl03-{src}-renamed-{short}", "atl03",
                                  h5(rename(full, full + "_old")),
                                  needles=(short,) if not optional else (),
                                  forbidden=("no usable photons",)))
                hows = ("scalar", "2d", "string", "short1", "half", "long", "empty")
                if short == "signal_conf_ph":
                    hows = ("scalar", "string", "short1", "empty")
                for how in hows:
                    cases.append(Case(f"atl03-{src}-reshaped-{short}-{how}", "atl03",
                                      h5(reshape(full, how))))
                cases.append(Case(f"atl03-{src}-retyped-{short}", "atl03",
                                  h5(reshape(full, "retype"))))
        # NaN, inf and fill values in the numeric datasets
        for ds in (ATL03_FLOATS if src == "vegr" else ("heights/h_ph", "heights/dist_ph_along")):
            short = ds.split("/")[-1]
            full = f"{beam}/{ds}"
            variants: list[tuple[str, float, float, bool]] = [
                ("nan-part", np.nan, 0.1, False), ("nan-all", np.nan, 1.0, False),
                ("inf-part", np.inf, 0.05, False), ("-inf-part", -np.inf, 0.05, False),
                ("fill-attr-part", F32_MAX, 0.1, True), ("fill-noattr-part", F32_MAX, 0.1, False),
                ("fill-attr-one", F32_MAX, 0.0, True), ("minus9999-attr-part", -9999.0, 0.1, True)]
            if src == "harmony":
                variants = variants[:1] + variants[4:6]
            for tag, value, frac, attr in variants:
                cases.append(Case(f"atl03-{src}-{short}-{tag}", "atl03",
                                  h5(set_values(full, value, frac, fill_attr=attr)),
                                  forbidden=("no usable photons",) if short != "h_ph"
                                  or frac < 1 else ()))
        for ds in (ATL03_INTS if src == "vegr" else ATL03_INTS[:1]):
            short = ds.split("/")[-1]
            full = f"{beam}/{ds}"
            for tag, value, frac, attr in (("fill-attr-part", 2**62, 0.1, True),
                                           ("negative-part", -5, 0.1, False),
                                           ("huge-part", 2**40, 0.1, False)):
                cases.append(Case(f"atl03-{src}-{short}-{tag}", "atl03",
                                  h5(set_values(full, value, frac, fill_attr=attr))))
        # empty beams and single photons
        cases.append(Case(f"atl03-{src}-no-photons", "atl03", h5(keep_photons(beam, 0)),
                          needles=("no photon", "empty", "no usable", "0 photons", "none")))
        cases.append(Case(f"atl03-{src}-one-photon", "atl03", h5(keep_photons(beam, 1))))
        cases.append(Case(f"atl03-{src}-two-photons", "atl03", h5(keep_photons(beam, 2))))
        cases.append(Case(f"atl03-{src}-empty-beam-group", "atl03", h5(empty_beam_group(beam)),
                          needles=("h_ph", "heights", "no photon", "empty", "missing")))
        cases.append(Case(f"atl03-{src}-all-counts-zero", "atl03",
                          h5(set_values(f"{beam}/geolocation/segment_ph_cnt", 0, 1.0))))
        if src == "vegr":  # the Harmony subset has no orbit_info
            cases.append(Case(f"atl03-{src}-no-orbit-info", "atl03", h5(delete("orbit_info"))))
    # the daytime granule without a signal filter (issue item 7): flag, do not report 250 m
    cases.append(Case("atl03-vegr-daytime-no-signal-filter", "atl03",
                      lambda d, b: {"path": b.vegr, "beam": "gt1r", "min_signal_conf": None},
                      warn_words=("noise", "background", "implausible")))
    return cases


def atl08_cases() -> list[Case]:
    cases: list[Case] = []
    g = "gt1r/signal_photons"

    def a8(fname: str, edit: Callable[[Path, Path], Path]) -> Callable[[Path, Base], Inputs]:
        def make(folder: Path, base: Base) -> Inputs:
            return {"path": edit(base.atl08, folder / fname), "atl03": base.vegr,
                    "beam": "gt1r", "original": base.atl08}
        return make

    for frac in (0.0, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99):
        cases.append(Case(f"atl08-truncated-{frac:g}", "atl08",
                          a8("atl08_trunc.h5", lambda p, d, fr=frac:
                             truncated(p, d, int(p.stat().st_size * fr))),
                          needles=BROKEN_WORDS))
    for ds in ("classed_pc_flag", "classed_pc_indx", "ph_segment_id", "delta_time"):
        cases.append(Case(f"atl08-deleted-{ds}", "atl08",
                          a8("atl08_edit.h5", lambda p, d, n=ds:
                             h5_edited(p, d, delete(f"{g}/{n}"))),
                          needles=(ds,) if ds != "delta_time" else ()))
        cases.append(Case(f"atl08-short-{ds}", "atl08",
                          a8("atl08_edit.h5", lambda p, d, n=ds:
                             h5_edited(p, d, reshape(f"{g}/{n}", "half")))))
    cases.append(Case("atl08-deleted-signal-photons", "atl08",
                      a8("atl08_edit.h5", lambda p, d: h5_edited(p, d, delete(g))),
                      needles=("signal_photons", "atl08")))
    for tag, value, frac in (("class-7", 7, 0.1), ("class-minus1", -1, 0.1),
                             ("class-127", 127, 0.05), ("class-all-7", 7, 1.0)):
        cases.append(Case(f"atl08-invalid-{tag}", "atl08",
                          a8("atl08_edit.h5", lambda p, d, v=value, fr=frac:
                             h5_edited(p, d, set_values(f"{g}/classed_pc_flag", v, fr))),
                          needles=("class",), warn_words=("class",)))
    for ds in ("ph_segment_id", "classed_pc_indx"):
        cases.append(Case(f"atl08-fill-{ds}", "atl08",
                          a8("atl08_edit.h5", lambda p, d, n=ds:
                             h5_edited(p, d, set_values(f"{g}/{n}", 2**31 - 1, 0.2,
                                                        fill_attr=True)))))
    cases.append(Case("atl08-delta-time-shifted", "atl08",
                      a8("atl08_edit.h5", lambda p, d: h5_edited(
                          p, d, shift(f"{g}/delta_time", 1000.0))),
                      needles=("match", "atl08")))
    cases.append(Case("atl08-segments-shifted", "atl08",
                      a8("atl08_edit.h5", lambda p, d: h5_edited(
                          p, d, shift(f"{g}/ph_segment_id", 100000))),
                      needles=("match", "join", "none", "no photon", "atl08"),
                      warn_words=("join", "match", "classified")))
    cases.append(Case("atl08-is-the-atl03", "atl08",
                      lambda d, b: {"path": b.vegr, "atl03": b.vegr, "beam": "gt1r",
                                    "original": b.atl08},
                      needles=("atl08",)))
    return cases


# ---- LAS / LAZ -----------------------------------------------------------------------------------

# LAS 1.0-1.4 public header offsets
H_VERSION, H_OFFSET_POINTS, H_FORMAT, H_RECLEN, H_COUNT = 24, 96, 104, 105, 107
H_SCALE, H_OFFSET, H_BOUNDS = 131, 155, 179  # 3 doubles; 3 doubles; maxx minx maxy miny maxz minz


def _las_header_lies(base: Base, src: Path) -> list[tuple[str, list[tuple[int, str, Any]]]]:
    import laspy

    with laspy.open(src) as reader:
        h = reader.header
    n = int(h.point_count)
    mins, maxs = [float(v) for v in h.mins], [float(v) for v in h.maxs]
    bounds = (maxs[0], mins[0], maxs[1], mins[1], maxs[2], mins[2])
    return [
        ("count-double", [(H_COUNT, "<I", 2 * n)]),
        ("count-half", [(H_COUNT, "<I", n // 2)]),
        ("count-zero", [(H_COUNT, "<I", 0)]),
        ("bounds-tiny", [(H_BOUNDS, "<6d", (mins[0] + 1, mins[0], mins[1] + 1, mins[1],
                                             mins[2] + 1, mins[2]))]),
        ("bounds-far", [(H_BOUNDS, "<6d", tuple(v + 1e6 for v in bounds))]),
        ("bounds-swapped", [(H_BOUNDS, "<6d", (mins[0], maxs[0], mins[1], maxs[1], mins[2],
                                               maxs[2]))]),
        ("bounds-nan", [(H_BOUNDS, "<6d", (float("nan"),) * 6)]),
        ("bounds-1e300", [(H_BOUNDS, "<6d", (1e300, -1e300, 1e300, -1e300, 1e300, -1e300))]),
        ("bounds-z-wrong", [(H_BOUNDS + 32, "<2d", (maxs[2] + 500.0, mins[2] - 500.0))]),
        ("zscale-zero", [(H_SCALE + 16, "<d", 0.0)]),
        ("xscale-zero", [(H_SCALE, "<d", 0.0)]),
        ("zscale-negative", [(H_SCALE + 16, "<d", -0.01)]),
        ("scale-nan", [(H_SCALE, "<3d", (float("nan"),) * 3)]),
        ("zscale-huge", [(H_SCALE + 16, "<d", 1e6)]),
        ("offset-nan", [(H_OFFSET, "<3d", (float("nan"),) * 3)]),
        ("offset-1e300", [(H_OFFSET, "<3d", (1e300, 1e300, 1e300))]),
        ("point-offset-plus8", [(H_OFFSET_POINTS, "<I", int(h.offset_to_point_data) + 8)]),
        ("point-offset-huge", [(H_OFFSET_POINTS, "<I", 2**31)]),
        ("record-length-wrong", [(H_RECLEN, "<H", int(h.point_format.size) + 4)]),
        ("format-99", [(H_FORMAT, "<B", 99)]),
        ("version-9", [(H_VERSION, "<2B", (9, 9))]),
        ("signature", [(0, "<4s", b"LASX")]),
        ("count-plus-5000", [(H_COUNT, "<I", n + 5000)]),
    ]


def _las_make(src_attr: str, fname: str, edit: Callable[[Path, Path], Path], **extra: Any
              ) -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        src = getattr(base, src_attr)
        return {"path": edit(src, folder / fname), "truth": base.conifer_points, **extra}
    return make


def _cloud_variant(kind: str) -> Callable[[Path, Base], Inputs]:
    """MixedConifer rewritten: other CRS/units, other classes, normalised, few points."""

    def make(folder: Path, base: Base) -> Inputs:
        import pyproj

        t = base.conifer_points
        x, y, z, c = t["x"].copy(), t["y"].copy(), t["z"].copy(), t["c"].copy()
        crs: Any = base_crs(base)
        truth = dict(t)
        ft = 1200.0 / 3937.0  # US survey foot in metres
        if kind == "no-crs":
            crs = None
        elif kind == "vertical-feet":  # UTM 12N + NAVD88 height (ftUS): z in feet
            crs = pyproj.CRS("EPSG:26912+6360")
            z = z / ft
        elif kind == "all-feet":  # a US-foot state plane, x/y/z in feet
            crs = pyproj.CRS("EPSG:2223")
            x, y, z = x / ft, y / ft, z / ft
        elif kind == "geographic":
            crs = pyproj.CRS("EPSG:4326")
            tr = pyproj.Transformer.from_crs(base_crs(base), "EPSG:4326", always_xy=True)
            x, y = tr.transform(x, y)
            return {"path": write_cloud(folder / "cloud.laz", x, y, z, c, crs, scale=1e-7),
                    "truth": truth}
        elif kind == "all-noise":
            c[:] = 7
        elif kind == "unclassified":
            c[:] = 1
        elif kind == "normalised":  # ground at z = 0 (heights above ground)
            g = c == 2
            z = z - np.median(z[g])
            z = np.maximum(z, 0.0)
            z[g] = 0.0
            truth = dict(t, z=z)
        elif kind == "one-point":
            x, y, z, c = x[:1], y[:1], z[:1], c[:1]
            truth = {"x": x, "y": y, "z": z, "c": c}
        elif kind == "no-points":
            x, y, z, c = x[:0], y[:0], z[:0], c[:0]
            truth = {"x": x, "y": y, "z": z, "c": c}
        elif kind == "z-spikes":  # a few absurd returns (birds, multipath): 5 km up
            z = z.copy()
            z[:: max(1, z.size // 20)] += 5000.0
            truth = dict(t, z=z)
        elif kind == "geokeys-vertical-feet":  # LAS 1.2 GeoTIFF keys: UTM 12N + NAVD88 ftUS
            keys = [(1024, 1), (3072, 26912), (3076, 9001), (4096, 6360), (4099, 9003)]
            return {"path": write_cloud_geokeys(folder / "cloud.laz", x, y, z / ft, c, keys),
                    "truth": truth}
        elif kind in ("terrain-100km", "terrain-below-500"):  # heights not on Earth
            z = z + (100_000.0 if kind == "terrain-100km" else -1_000.0)
            truth = dict(t, z=z)
        elif kind == "flat-duplicates":  # every point at one position
            x = np.full_like(x, x[0])
            y = np.full_like(y, y[0])
            truth = dict(t, x=x, y=y)
        else:
            raise ValueError(kind)
        return {"path": write_cloud(folder / "cloud.laz", x, y, z, c, crs), "truth": truth}

    return make


def base_crs(base: Base) -> Any:
    import laspy

    with laspy.open(base.conifer) as reader:
        return reader.header.parse_crs()


CLOUD_VARIANTS = ("no-crs", "vertical-feet", "all-feet", "geographic", "all-noise",
                  "unclassified", "normalised", "one-point", "no-points", "z-spikes",
                  "flat-duplicates", "geokeys-vertical-feet", "terrain-100km",
                  "terrain-below-500")
#: Refused by every reader: heights in feet stated by GeoTIFF keys, terrain off the Earth.
_REFUSED_VARIANTS = {"geokeys-vertical-feet": ("feet", "foot"),
                     "terrain-100km": ("earth",), "terrain-below-500": ("earth",)}


def las_cases() -> list[Case]:
    cases: list[Case] = []
    for src_attr, suffix in (("conifer", "laz"), ("conifer_las", "las")):
        for frac in (0.0, 0.001, 0.05, 0.2, 0.5, 0.8, 0.95, 0.999):
            cases.append(Case(f"{suffix}-truncated-{frac:g}", "las",
                              _las_make(src_attr, f"cloud_trunc.{suffix}",
                                        lambda p, d, fr=frac:
                                        truncated(p, d, int(p.stat().st_size * fr))),
                              needles=BROKEN_WORDS,
                              forbidden=("states no crs", "no points inside", "inside bbox")))
        cases.append(Case(f"{suffix}-truncated-last-byte", "las",
                          _las_make(src_attr, f"cloud_trunc.{suffix}",
                                    lambda p, d: truncated(p, d, p.stat().st_size - 1)),
                          needles=BROKEN_WORDS,
                          forbidden=("states no crs", "no points inside", "inside bbox")))

        names = ("count-double", "count-half", "count-zero", "bounds-tiny", "bounds-far",
                 "bounds-swapped", "bounds-nan", "bounds-1e300", "bounds-z-wrong",
                 "zscale-zero", "xscale-zero", "zscale-negative", "scale-nan", "zscale-huge",
                 "offset-nan", "offset-1e300", "point-offset-plus8", "point-offset-huge",
                 "record-length-wrong", "format-99", "version-9", "signature",
                 "count-plus-5000")
        for i, name in enumerate(names):
            def make(folder: Path, base: Base, i: int = i, src_attr: str = src_attr,
                     suffix: str = suffix) -> Inputs:
                src = getattr(base, src_attr)
                patches = _las_header_lies(base, src)[i][1]
                return {"path": patched(src, folder / f"cloud_lie.{suffix}", patches),
                        "truth": base.conifer_points}
            counted = name == "count-plus-5000"  # the count named, not the decompressor
            cases.append(Case(f"{suffix}-header-{name}", "las", make,
                              needles=("its header counts",) if counted else (),
                              must_refuse=counted,
                              forbidden=("states no crs", "no points inside",
                                         "fill whole buffer", "ioerror")))
        rng = np.random.default_rng(11 if suffix == "laz" else 12)
        for i in range(4):
            pos = [int(v) for v in rng.integers(0, 227, size=2)]
            cases.append(Case(f"{suffix}-bitflip-header-{i}", "las",
                              _las_make(src_attr, f"cloud_flip.{suffix}",
                                        lambda p, d, pos=pos: bit_flipped(p, d, pos))))
    for kind in CLOUD_VARIANTS:
        needles = {"no-crs": ("crs",), "vertical-feet": ("feet", "foot", "unit", "metre"),
                   "all-feet": ("feet", "foot", "unit", "metre"),
                   "geographic": ("metric", "degree", "geographic", "projected", "crs"),
                   "no-points": ("no point", "empty", "0 points")}.get(kind, ())
        needles = _REFUSED_VARIANTS.get(kind, needles)
        for runner in ("las", "simulate"):
            if runner == "las" and kind in ("vertical-feet", "all-feet", "geographic"):
                continue  # reading them is fine; what is made of them is checked
            cases.append(Case(f"cloud-{kind}-{runner}", runner, _cloud_variant(kind),
                              needles=needles, must_refuse=kind in _REFUSED_VARIANTS,
                              warn_words=("normalis", "normaliz", "above ground", "ground at")
                              if kind == "normalised" and runner == "simulate" else ()))
    # PDAL rasters: a sample of the damaged clouds (each run takes about a second)
    for kind in ("no-crs", "vertical-feet", "all-feet", "geographic", "all-noise",
                 "unclassified", "normalised", "one-point", "z-spikes",
                 *_REFUSED_VARIANTS):
        needles = _REFUSED_VARIANTS.get(kind) or {
            "all-noise": ("noise", "class"), "unclassified": ("ground", "smrf"),
            "no-crs": ("crs",), "vertical-feet": ("feet", "foot", "unit"),
            "all-feet": ("feet", "foot", "unit"),
            "geographic": ("metric", "degree", "geographic", "crs")}.get(kind, ())
        cases.append(Case(f"cloud-{kind}-rasters", "rasters", _cloud_variant(kind), pdal=True,
                          needles=needles, must_refuse=kind in _REFUSED_VARIANTS,
                          forbidden=("check the bounds/crs",) if kind == "all-noise" else (),
                          warn_words=("normalis", "normaliz", "above ground", "ground at")
                          if kind == "normalised" else ()))
    for name, frac in (("truncated-0.5", 0.5), ("truncated-0.95", 0.95)):
        cases.append(Case(f"laz-{name}-rasters", "rasters",
                          _las_make("conifer", "cloud_trunc.laz", lambda p, d, fr=frac:
                                    truncated(p, d, int(p.stat().st_size * fr))),
                          pdal=True, needles=BROKEN_WORDS,
                          forbidden=("states no crs", "no points inside")))
    for name in ("bounds-tiny", "bounds-far", "bounds-nan", "bounds-1e300", "zscale-zero",
                 "count-double"):
        def make_r(folder: Path, base: Base, name: str = name) -> Inputs:
            lies = dict(_las_header_lies(base, base.conifer_las))
            return {"path": patched(base.conifer_las, folder / "cloud_lie.las", lies[name]),
                    "truth": base.conifer_points}
        cases.append(Case(f"las-header-{name}-rasters", "rasters", make_r, pdal=True))
    return cases


# ---- reference rasters ---------------------------------------------------------------------------


def _raster_variant(kind: str, which: str = "dtm") -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        import rasterio
        from rasterio.transform import Affine

        r = base.rasters
        src = r["paths"][which]
        paths = dict(r["paths"])
        out = folder / f"{which}.tif"
        with rasterio.open(src) as s:
            data = s.read(1)
            prof = s.profile.copy()
        valid = data != -9999.0
        if kind.startswith("undeclared-"):
            v = {"undeclared-9999": -9999.0, "undeclared-f32max": F32_MAX,
                 "undeclared-nan": np.nan}[kind]
            data = np.where(valid, data, v).astype("float32")
            prof["nodata"] = None
        elif kind == "declared-f32max":
            data = np.where(valid, data, F32_MAX).astype("float32")
            prof["nodata"] = F32_MAX
        elif kind == "all-zero":
            data = np.zeros_like(data)
            prof["nodata"] = None
        elif kind == "all-nodata":
            data = np.full_like(data, -9999.0)
        elif kind == "half-cell-shift":
            t = prof["transform"]
            prof["transform"] = Affine(t.a, t.b, t.c + t.a / 2, t.d, t.e, t.f)
        elif kind == "other-resolution":
            t = prof["transform"]
            prof["transform"] = Affine(t.a * 2, t.b, t.c, t.d, t.e * 2, t.f)
        elif kind == "far-away":
            t = prof["transform"]
            prof["transform"] = Affine(t.a, t.b, t.c + 1e5, t.d, t.e, t.f)
        elif kind == "no-crs":
            prof["crs"] = None
        elif kind == "wrong-crs":
            prof["crs"] = "EPSG:32612"
        elif kind == "geographic-crs":
            prof["crs"] = "EPSG:4326"
        elif kind == "feet-values":  # heights in US feet, labelled with a foot vertical CRS
            data = np.where(valid, data / (1200.0 / 3937.0), -9999.0).astype("float32")
            prof["crs"] = "EPSG:2949+6360"
        elif kind == "feet-values-unlabelled":
            data = np.where(valid, data / (1200.0 / 3937.0), -9999.0).astype("float32")
        elif kind == "int16":
            data = np.where(valid, np.round(data), -9999).astype("int16")
            prof["dtype"] = "int16"
            prof["nodata"] = -9999
        elif kind == "two-bands":
            prof["count"] = 2
        elif kind == "one-cell":
            data = data[:1, :1]
            prof["width"] = prof["height"] = 1
        elif kind == "rotated":
            t = prof["transform"]
            prof["transform"] = Affine(t.a, 0.5, t.c, 0.5, t.e, t.f)
        elif kind in ("truncated", "bitflip", "text"):
            pass
        else:
            raise ValueError(kind)
        if kind == "truncated":
            truncated(src, out, src.stat().st_size // 2)
        elif kind == "bitflip":
            bit_flipped(src, out, [int(v) for v in np.random.default_rng(3).integers(0, 400, 6)])
        elif kind == "text":
            out.write_text("not a raster\n")
        else:
            with rasterio.open(out, "w", **prof) as dst:
                for b in range(1, prof["count"] + 1):
                    dst.write(data, b)
        paths[which] = out
        return {"path": out, "rasters": paths, "blocks": base.blocks,
                "ranges": r["ranges"]}

    return make


RASTER_VARIANTS = ("undeclared-9999", "undeclared-f32max", "undeclared-nan", "declared-f32max",
                   "all-zero", "all-nodata", "half-cell-shift", "other-resolution", "far-away",
                   "no-crs", "wrong-crs", "geographic-crs", "feet-values",
                   "feet-values-unlabelled", "int16", "two-bands", "one-cell", "rotated",
                   "truncated", "bitflip", "text")


def raster_cases() -> list[Case]:
    cases = []
    for which in ("dtm", "dsm_max"):
        for kind in RASTER_VARIANTS:
            if which == "dsm_max" and kind in ("rotated", "two-bands", "int16", "one-cell"):
                continue
            needles = {"truncated": BROKEN_WORDS, "bitflip": (),
                       "text": BROKEN_WORDS + ("raster", "geotiff")}.get(kind, ())
            cases.append(Case(f"tif-{which}-{kind}", "validate", _raster_variant(kind, which),
                              needles=needles))
    return cases


# ---- photon tables --------------------------------------------------------------------------------


def _table_variant(kind: str) -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        import pandas as pd

        df = pd.read_csv(base.photon_csv)
        out = folder / "photons.csv"
        rng = np.random.default_rng(5)
        m = rng.random(len(df)) < 0.1
        if kind == "nan-h":
            df.loc[m, "h"] = np.nan
        elif kind == "inf-h":
            df.loc[m, "h"] = np.inf
        elif kind == "fill-h":
            df.loc[m, "h"] = F32_MAX
        elif kind == "nan-lat":
            df.loc[m, "lat"] = np.nan
        elif kind == "lat-out-of-range":
            df.loc[m, "lat"] = 123.0
        elif kind == "text-h":
            df["h"] = df["h"].astype(object)
            df.loc[m, "h"] = "n/a"
        elif kind == "no-h":
            df = df.drop(columns="h")
        elif kind == "no-lat":
            df = df.drop(columns="lat")
        elif kind == "header-only":
            df = df.iloc[:0]
        elif kind == "one-row":
            df = df.iloc[:1]
        elif kind == "all-nan-h":
            df["h"] = np.nan
        elif kind == "empty-file":
            out.write_text("")
            return {"path": out}
        elif kind == "binary":
            out.write_bytes(bytes(range(256)) * 8)
            return {"path": out}
        elif kind == "duplicated":
            df = pd.concat([df, df])
        else:
            raise ValueError(kind)
        df.to_csv(out, index=False)
        return {"path": out}

    return make


TABLE_VARIANTS = ("nan-h", "inf-h", "fill-h", "nan-lat", "lat-out-of-range", "text-h", "no-h",
                  "no-lat", "header-only", "one-row", "all-nan-h", "empty-file", "binary",
                  "duplicated")


def table_cases() -> list[Case]:
    needles = {"no-h": ("h", "column"), "no-lat": ("lat", "column"),
               "header-only": ("no rows", "empty", "no photon"),
               "empty-file": ("empty", "no rows", "no columns", "cannot read"),
               "binary": BROKEN_WORDS + ("column",)}
    return [Case(f"table-{k}", "table", _table_variant(k), needles=needles.get(k, ()))
            for k in TABLE_VARIANTS]


# ---- bad parameters (API) ----------------------------------------------------------------------------


def _param(name: str) -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        return {"path": None, "call": name, "vegr": base.vegr, "conifer": base.conifer,
                "folder": folder}
    return make


PARAM_CASES: dict[str, tuple[str, ...]] = {
    # call name -> words the refusal must contain (any)
    "compute_blocks-None": ("track", "none"),
    "compute_blocks-path": ("track", "path", "str"),
    "compute_blocks-geodataframe": ("track", "geodataframe", "dataframe"),
    "read_atl03-None": ("path", "none", "file"),
    "read_atl03-beam-int": ("beam",),
    "read_atl03-beam-unknown": ("beam",),
    "blocks_from_file-beams-str": ("beam",),
    "blockparams-lengths-str": ("length",),
    "blockparams-lengths-zero": ("length",),
    "blockparams-lengths-negative": ("length",),
    "blockparams-lengths-nan": ("length",),
    "blockparams-k-str": ("k_sigma", "k"),
    "blockparams-min-photons-negative": ("min_photons",),
    "blockparams-top-cutoff-2": ("top_cutoff", "cutoff"),
    "simparams-shot-spacing-tiny": ("shot", "spacing", "memory", "gib", "too many"),
    "simparams-mean-photons-1e9": ("mean_photons", "photons", "memory", "gib"),
    "simparams-noise-rate-1e6": ("noise", "memory", "gib"),
    "simulate-seed-negative": ("seed",),
    "error_stats-empty": ("empty", "no ", "nothing"),
    "read_las-None": ("path", "none", "file"),
    "read_las-empty-list": ("no ", "file"),
    "read_las-text-file": BROKEN_WORDS + ("las",),
    "rasters-resolution-zero": ("resolution",),
    "rasters-resolution-nan": ("resolution",),
    "rasters-resolution-tiny": ("cells", "resolution", "grid"),
}


def param_cases() -> list[Case]:
    return [Case(f"param-{name}", "param", _param(name), needles=needles,
                 pdal=name.startswith("rasters"))
            for name, needles in PARAM_CASES.items()]


# ---- the command line, in-process and as subprocesses -----------------------------------------------


def _cli(args: Callable[[Path, Base, Inputs], list[str]], inner: Callable[[Path, Base], Inputs],
         outputs: Callable[[Path], list[Path]]) -> Callable[[Path, Base], Inputs]:
    def make(folder: Path, base: Base) -> Inputs:
        inputs = inner(folder, base)
        inputs["args"] = args(folder, base, inputs)
        inputs["outputs"] = outputs(folder)
        return inputs
    return make


def _blocks_args(folder: Path, base: Base, i: Inputs) -> list[str]:
    args = ["blocks", str(i["path"]), "-o", str(folder / "out" / "blocks.gpkg"), "--length",
            "25"]
    if i.get("min_signal_conf") is not None:  # the preset that uses it (atl08 refuses it)
        args += ["--preset", "icesat2", "--min-signal-conf", str(i["min_signal_conf"])]
    return args


def _simulate_args(folder: Path, base: Base, i: Inputs) -> list[str]:
    return ["simulate", str(i["path"]), "--azimuth", "0", "--realisations", "2",
            "-o", str(folder / "out" / "sim.h5"), "--report", str(folder / "out" / "report")]


def _rasters_args(folder: Path, base: Base, i: Inputs) -> list[str]:
    return ["rasters", str(i["path"]), "-o", str(folder / "out" / "rasters"),
            "--resolution", "2"]


def _validate_args(folder: Path, base: Base, i: Inputs) -> list[str]:
    r = i["rasters"]
    return ["validate", str(i["blocks"]), "--dtm", str(r["dtm"]), "--dsm-max",
            str(r["dsm_max"]), "--dsm-p90", str(r["dsm_p90"]), "--offset", "0", "--width", "13",
            "-o", str(folder / "out" / "validation.gpkg")]


def cli_cases() -> list[Case]:
    cases: list[Case] = []
    atl03 = {c.id: c for c in atl03_cases()}
    for cid in ("atl03-vegr-truncated-0.5", "atl03-vegr-deleted-h_ph", "atl03-vegr-h_ph-nan-part",
                "atl03-vegr-dist_ph_along-fill-noattr-part", "atl03-vegr-reshaped-h_ph-string",
                "atl03-vegr-no-photons", "atl03-vegr-one-photon", "atl03-harmony-bitflip-head-0",
                "atl03-vegr-segment_ph_cnt-huge-part", "atl03-vegr-h_ph-fill-attr-part"):
        c = atl03[cid]
        cases.append(Case(f"cli-blocks-{cid}", "cli",
                          _cli(_blocks_args, c.make, lambda d: [d / "out" / "blocks.gpkg"]),
                          needles=c.needles, forbidden=c.forbidden))
    las = {c.id: c for c in las_cases()}
    for cid in ("laz-truncated-0.5", "las-truncated-0.8", "las-header-bounds-nan",
                "las-header-zscale-zero", "cloud-vertical-feet-simulate",
                "cloud-normalised-simulate", "cloud-all-noise-simulate",
                "cloud-no-crs-simulate", "las-header-bounds-tiny", "las-header-bounds-swapped",
                "las-header-bounds-1e300", "laz-header-bounds-far",
                "cloud-geokeys-vertical-feet-simulate", "cloud-terrain-100km-simulate"):
        c = las[cid]
        # a lying header or a noise-only tile is not the track's or the footprint's fault
        wrong_cause = ("smaller than twice the inset", "smaller footprint", "no points in",
                       "misses the point cloud", "simulation parameters")
        cases.append(Case(f"cli-simulate-{cid}", "cli",
                          _cli(_simulate_args, c.make,
                               lambda d: [d / "out" / "sim.h5", d / "out" / "report"]),
                          needles=c.needles, forbidden=c.forbidden + wrong_cause,
                          warn_words=c.warn_words, must_refuse=c.must_refuse))
    for cid in ("laz-truncated-0.5", "cloud-all-noise-rasters", "cloud-vertical-feet-rasters",
                "las-header-bounds-1e300-rasters"):
        c = las[cid]
        cases.append(Case(f"cli-rasters-{cid}", "cli",
                          _cli(_rasters_args, c.make, lambda d: [d / "out" / "rasters"]),
                          needles=c.needles, forbidden=c.forbidden, pdal=True))
    tif = {c.id: c for c in raster_cases()}
    for cid in ("tif-dtm-undeclared-9999", "tif-dtm-undeclared-f32max", "tif-dtm-all-zero",
                "tif-dtm-truncated", "tif-dsm_max-other-resolution", "tif-dtm-feet-values"):
        c = tif[cid]
        cases.append(Case(f"cli-validate-{cid}", "cli",
                          _cli(_validate_args, c.make,
                               lambda d: [d / "out" / "validation.gpkg"]),
                          needles=c.needles))
    # bad numbers on the command line
    for opt, value, needle in (("--seed", "-1", "seed"), ("--shot-spacing", "0.00001", "spacing"),
                               ("--mean-photons", "1e9", "photons"),
                               ("--noise-rate", "1e6", "noise"),
                               ("--realisations", "abc", "realisations"),
                               ("--diameter", "nan", "diameter"),
                               ("--telemetry-window", "1e5", "telemetry"),
                               ("--background-rate", "1000", "1 ghz")):
        def args_p(folder: Path, base: Base, i: Inputs, opt: str = opt, value: str = value
                   ) -> list[str]:
            return ["simulate", str(base.conifer), "--azimuth", "0", "--realisations", "2",
                    opt, value, "-o", str(folder / "out" / "sim.h5")]
        cases.append(Case(f"cli-simulate-option{opt}={value}", "cli",
                          _cli(args_p, lambda d, b, opt=opt: {"path": None, "name": opt},
                               lambda d: [d / "out" / "sim.h5"]),
                          needles=(needle,)))
    # outputs that cannot be written
    cases.append(Case("cli-simulate-report-unwritable", "cli",
                      _cli(lambda d, b, i: ["simulate", str(b.conifer), "--azimuth", "0",
                                            "--realisations", "2", "-o", str(d / "out" / "s.h5"),
                                            "--report", "/proc/canopyblocks/report"],
                           lambda d, b: {"path": None, "name": "/proc/canopyblocks"},
                           lambda d: [d / "out" / "s.h5"]),
                      needles=("write", "writable", "permission", "cannot")))
    cases.append(Case("cli-blocks-output-in-a-file", "cli",
                      _cli(lambda d, b, i: ["blocks", str(b.vegr), "-o",
                                            str(b.vegr) + "/blocks.gpkg"],
                           lambda d, b: {"path": None, "name": "blocks.gpkg"},
                           lambda d: []),
                      needles=("folder", "file", "write")))
    cases.extend(_batch_cli_cases())
    return cases


def _batch_granules(folder: Path, base: Base) -> Inputs:
    grans = folder / "granules"
    grans.mkdir(parents=True, exist_ok=True)
    shutil.copy(base.vegr, grans / "ATL03_vegr.h5")
    return {"path": grans, "name": "granules"}


def _batch_cli_cases() -> list[Case]:
    """``batch`` refuses an output folder that is (or lies inside) its input folder, and
    ellipsoidal photons against orthometric tiles without a conversion, before any work."""
    cases = []
    for where, sub in (("is", ""), ("inside", "results")):
        cases.append(Case(
            f"cli-batch-output-{where}-input-folder", "cli",
            _cli(lambda d, b, i, sub=sub: ["batch", str(i["path"]), "--tiles", str(b.conifer),
                                           "--offset", "0", "--backend", "serial", "-o",
                                           str(i["path"] / sub if sub else i["path"])],
                 _batch_granules, lambda d: [d / "granules" / "manifest.json",
                                             d / "granules" / "results"]),
            needles=("input folder",), must_refuse=True))

    def bcts(folder: Path, base: Base) -> Inputs:
        return {**_batch_granules(folder, base), "tile": base.data_file("als/lasR_bcts_1.laz"),
                "name": "lasR_bcts_1.laz"}
    cases.append(Case(
        "cli-batch-ellipsoidal-vs-cgvd28-no-conversion", "cli",
        _cli(lambda d, b, i: ["batch", str(i["path"]), "--tiles", str(i["tile"]),
                              "--backend", "serial", "-o", str(d / "out")],
             bcts, lambda d: [d / "out"]),
        needles=("CGVD28",), must_refuse=True))
    return cases


SUBPROCESS_SAMPLE = ("cli-baseline-simulate", "cli-blocks-atl03-vegr-truncated-0.5",
                     "cli-blocks-atl03-vegr-dist_ph_along-fill-noattr-part",
                     "cli-simulate-las-truncated-0.8",
                     "cli-simulate-option--shot-spacing=0.00001",
                     "cli-rasters-laz-truncated-0.5",
                     "cli-validate-tif-dtm-undeclared-9999",
                     "cli-simulate-report-unwritable",
                     "cli-waveforms-gedi-rxwaveform-2d", "cli-waveforms-gedi-sample-1e6",
                     "cli-waveforms-gedi-count-strings")
"""CLI cases also run as real subprocesses (the others run in-process through run_main)."""


def baseline_cases() -> list[Case]:
    """The undamaged samples through every runner: accepted, and confirmed."""
    def same(attr: str, **extra: Any) -> Callable[[Path, Base], Inputs]:
        def make(folder: Path, base: Base) -> Inputs:
            p = getattr(base, attr)
            dst = folder / p.name
            shutil.copyfile(p, dst)
            return {"path": dst, **{k: (v(base) if callable(v) else v)
                                     for k, v in extra.items()}}
        return make

    truth = {"truth": lambda b: b.conifer_points}
    cases = [
        Case("baseline-atl03-vegr", "atl03", same("vegr", beam="gt1r", min_signal_conf=2),
             must_accept=True),
        Case("baseline-atl03-harmony", "atl03",
             same("harmony", beam="gt1l", min_signal_conf=None), must_accept=True),
        Case("baseline-atl08", "atl08", same("atl08", atl03=lambda b: b.vegr, beam="gt1r",
                                             original=lambda b: b.atl08), must_accept=True),
        Case("baseline-laz", "las", same("conifer", **truth), must_accept=True),
        Case("baseline-las", "las", same("conifer_las", **truth), must_accept=True),
        Case("baseline-simulate", "simulate", same("conifer", **truth), must_accept=True),
        Case("baseline-rasters", "rasters", same("conifer", **truth), must_accept=True,
             pdal=True),
        Case("baseline-table", "table", same("photon_csv"), must_accept=True),
    ]

    def validate_make(folder: Path, base: Base) -> Inputs:
        r = base.rasters
        return {"path": r["paths"]["dtm"], "rasters": dict(r["paths"]), "blocks": base.blocks,
                "ranges": r["ranges"]}
    cases.append(Case("baseline-validate", "validate", validate_make, must_accept=True))
    cases.append(Case("cli-baseline-blocks", "cli",
                      _cli(_blocks_args, same("vegr", beam="gt1r", min_signal_conf=2),
                           lambda d: [d / "out" / "blocks.gpkg"]), must_accept=True))
    cases.append(Case("cli-baseline-simulate", "cli",
                      _cli(_simulate_args, same("conifer", **truth),
                           lambda d: [d / "out" / "sim.h5", d / "out" / "report"]),
                      must_accept=True))
    cases.append(Case("cli-baseline-validate", "cli",
                      _cli(_validate_args, validate_make,
                           lambda d: [d / "out" / "validation.gpkg"]), must_accept=True))
    return cases


def url_cases() -> list[Case]:
    """The damaged vegr ATL03 granules once more, read from a loopback HTTP server by range
    requests (``https://`` in use): the same outcome as the local file, the URL named."""
    from dataclasses import replace

    vegr = [c for c in atl03_cases() if c.id.startswith("atl03-vegr-")]
    # every truncation and bit flip (what a dropped transfer leaves), a sample of the rest
    picked = [c for i, c in enumerate(vegr)
              if "truncated" in c.id or "bitflip" in c.id or i % 8 == 0]
    return [replace(c, id=f"url-{c.id}", runner="atl03-url") for c in picked]


def all_cases() -> list[Case]:
    from .api_corpus import api_cases
    from .copc_corpus import copc_cases
    from .coregistration_cases import coregistration_cases
    from .gedi_corpus import gedi_cases
    from .issue29_corpus import issue29_cases
    from .odd_inputs_corpus import odd_cases
    from .options_corpus import options_cases
    from .survey_corpus import survey_cases

    cases = (baseline_cases() + atl03_cases() + atl08_cases() + las_cases() + raster_cases() + table_cases()
             + param_cases() + cli_cases() + gedi_cases()
             + coregistration_cases() + api_cases() + issue29_cases() + odd_cases()
             + url_cases() + copc_cases() + survey_cases()
             + options_cases())
    ids = [c.id for c in cases]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise AssertionError(f"duplicate corpus ids: {sorted(dup)}")
    return cases
