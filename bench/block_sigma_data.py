"""Blocks of the ``atl08`` preset with the sigma model's quantities and their residuals
against the footprint-matched reference, on simulated ICESat-2 tracks (the yardstick of
``bench_icesat2_accuracy.py``: leak-free photons over airborne tiles, written as ATL03
files and read back; background uniform in the telemetry window).

Shared by ``fit_block_sigma.py`` (calibration tiles only) and ``bench_block_sigma.py``
(the unseen tiles). Lights: night 0.15 MHz, day 1.5 / 3 / 4.5 MHz; strong and weak beams;
six azimuths; block lengths 10, 25, 50 and 100 m (``s0 = 0``).

Geolocation error: the photons are simulated at the true place and the track is reported
``offset`` m (0, 3, 6) away from it, in a random direction drawn once per line and offset
(its beams and lights share it; fixed seeds): the reference is taken along the reported
line, as a user's check against airborne data would be. The block quantities do not
change with the offset (the photons' heights and along-track distances are the same).

``site_blocks(name, tiles, seed)`` returns one row per block and offset with a reference:
``site, azimuth, beam, light, offset, length, block, hmax, ground, flag``, the quantities of
``blocks.uncertainty.block_features`` and ``ref_ground, ref_hmax`` (footprint-matched:
mean footprint ground, ground + RH98), ``res_hmax = hmax - ref_hmax``,
``res_ground = ground - ref_ground`` (metres).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

# the accuracy bench's calibration tiles and unseen tiles: one list for both benches
from icesat2_scoring import CAL_TILES, TEST_SITES  # noqa: E402

from canopyblocks.blocks import BlockParams
from canopyblocks.blocks.atl08_blocks import atl08_block_table
from canopyblocks.blocks.atl08_classify import classify_photons
from canopyblocks.blocks.estimators import preset
from canopyblocks.blocks.uncertainty import block_features
from canopyblocks.readers import read_atl03
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.reference.footprint import FootprintCloud, block_footprint_reference
from canopyblocks.reference.footprint_params import FootprintReferenceParams
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.engine import cloud_index
from canopyblocks.simulate.writers import write_simulation_atl03

LIGHTS: dict[str, float] = {"night": 0.15, "day 1.5 MHz": 1.5, "day 3 MHz": 3.0,
                            "day 4.5 MHz": 4.5}
BEAMS = ("strong", "weak")
LENGTHS = (10.0, 25.0, 50.0, 100.0)
AZIMUTHS = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0)
OFFSETS = (0.0, 3.0, 6.0)
DIAMETER = 13.0


def with_relief(pts: LasPoints, grade: float, amplitude: float, wavelength: float
                ) -> LasPoints:
    """The points on synthetic relief: every height raised by ``grade`` x (x - x0) plus
    ``amplitude`` x sin(2 pi (x + y) / wavelength) (m): the same canopy over sloping,
    rolling ground (a way to show a flat calibration tile what relief does)."""
    x0 = float(np.min(pts.x))
    dz = grade * (pts.x - x0) + amplitude * np.sin(2 * np.pi * (pts.x + pts.y) / wavelength)
    return replace(pts, z=pts.z + dz)


def _references(line, lengths: tuple[float, ...], cloud: FootprintCloud,
                shift: tuple[float, float]) -> pd.DataFrame | None:
    """Footprint-matched reference of every block of ``line`` moved by ``shift`` (m)."""
    (x0, y0), (x1, y1) = line.vertices
    dx, dy = (x1 - x0) / line.length, (y1 - y0) / line.length
    refs = []
    for length in lengths:
        nb = int(line.length // length)
        if nb < 2:  # the reference follows the line through >= 2 centres
            continue
        s_mid = (np.arange(nb) + 0.5) * length
        rb = pd.DataFrame({"track": "ref", "length": length, "block": np.arange(nb),
                           "s_start": s_mid - length / 2, "s_end": s_mid + length / 2,
                           "x": x0 + dx * s_mid + shift[0], "y": y0 + dy * s_mid + shift[1]})
        fp = block_footprint_reference(rb, cloud)
        refs.append(pd.DataFrame({
            "length": length, "block": np.arange(nb),
            "ref_ground": fp["ref_ground"].to_numpy(float),
            "ref_hmax": fp["ref_hmax"].to_numpy(float),
            "ref_ok": (fp["ref_flag"] == "ok").to_numpy()}))
    return pd.concat(refs, ignore_index=True) if refs else None


def _track_blocks(t, lengths: tuple[float, ...], params: BlockParams, est) -> pd.DataFrame | None:
    """The atl08 blocks of one read-back track with the sigma model's quantities."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            classes = classify_photons(t, est.atl08)
            blocks, _ = atl08_block_table(t, params, classes)
        except Exception:  # noqa: BLE001 -- no signal on this track
            return None
    rows = []
    for length in lengths:
        sub = blocks[blocks["length"] == length].sort_values("s_start")
        if not len(sub):
            continue
        f = block_features(t, classes, sub["s_start"].to_numpy(float),
                           sub["s_end"].to_numpy(float), sub["hmax"].to_numpy(float))
        d = pd.DataFrame(f)
        d["length"] = length
        d["block"] = sub["block"].to_numpy()
        d["ground"] = sub["ground"].to_numpy(float)
        d["flag"] = sub["flag"].to_numpy()
        rows.append(d)
    return pd.concat(rows, ignore_index=True) if rows else None


def site_blocks(name: str, tiles: tuple[Path, ...], seed: int, *,
                azimuths: tuple[float, ...] = AZIMUTHS,
                lengths: tuple[float, ...] = LENGTHS,
                offsets: tuple[float, ...] = OFFSETS,
                relief: tuple[float, float, float] | None = None,
                cache: str | os.PathLike[str] | None = None) -> pd.DataFrame:
    """Blocks of every (azimuth, beam, light) track of a site, reported at every offset
    (see the module notes); ``relief``: (grade, amplitude m, wavelength m) of
    :func:`with_relief`; read from / written to ``cache`` (a parquet file) when given."""
    if cache is not None and Path(cache).exists():
        return pd.read_parquet(cache)
    pts = read_las([str(t) for t in tiles])
    if relief is not None:
        pts = with_relief(pts, *relief)
    cloud = FootprintCloud(pts, FootprintReferenceParams())
    index = cloud_index(pts, SimParams())
    est = preset("atl08")
    params = BlockParams(lengths=tuple(lengths), s0=0.0)
    frames = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, az in enumerate(azimuths):
            line = line_through(pts.bounds, az, inset=DIAMETER / 2 + 3.0 + max(offsets))
            rng = np.random.default_rng([seed, i, 7])
            refs = {}
            for off in offsets:
                ang = rng.uniform(0.0, 2 * np.pi)
                refs[off] = _references(line, lengths, cloud,
                                        (off * np.cos(ang), off * np.sin(ang)))
            if refs[offsets[0]] is None:
                continue
            for beam in BEAMS:
                for j, (light, mhz) in enumerate(LIGHTS.items()):
                    sim = simulate_photons(pts, line, SimParams(beam=beam,
                                                                background_rate_mhz=mhz),
                                           seed=seed + 100 * i + 10 * j + (beam == "weak"),
                                           index=index)
                    path = write_simulation_atl03(sim, Path(tmp) / "t.h5")
                    t = read_atl03(path, "gt1r", crs=pts.crs)
                    d0 = _track_blocks(t, lengths, params, est)
                    if d0 is None:
                        continue
                    for off, ref in refs.items():
                        d = d0.merge(ref, on=["length", "block"])
                        d = d[d["ref_ok"]].drop(columns="ref_ok")
                        d["site"], d["azimuth"], d["beam"], d["light"] = name, az, beam, light
                        d["offset"] = off
                        frames.append(d)
    out = pd.concat(frames, ignore_index=True)
    out["res_hmax"] = out["hmax"] - out["ref_hmax"]
    out["res_ground"] = out["ground"] - out["ref_ground"]
    if cache is not None:
        Path(cache).parent.mkdir(parents=True, exist_ok=True)
        out.to_parquet(cache)
    return out


def calibration_blocks(cache_dir: str | os.PathLike[str] | None = None) -> pd.DataFrame:
    """Blocks of the calibration tiles (seed 1, as the accuracy bench's calibration)."""
    c = None if cache_dir is None else Path(cache_dir) / "cal.parquet"
    return site_blocks("lasR_bcts", CAL_TILES, seed=1, cache=c)


def unseen_blocks(cache_dir: str | os.PathLike[str] | None = None) -> pd.DataFrame:
    """Blocks of the three unseen tiles (seed 1000, as the accuracy bench's test)."""
    frames = []
    for n, t in TEST_SITES.items():
        c = None if cache_dir is None else Path(cache_dir) / f"{n}.parquet"
        frames.append(site_blocks(n, t, seed=1000, cache=c))
    return pd.concat(frames, ignore_index=True)
