"""Simulated GEDI waveforms, flash-array cubes and dual-wavelength pairs over airborne
tiles, as files.

What ``canopyblocks simulate LAS --sensor gedi|esfl|dual`` writes: one HDF5 file (atomic) with
the simulated data and their truth, and optionally a report folder with the method's
study (seed 003's energy-threshold table, or seed 004's ground error against cover).

Layouts (HDF5, metres unless stated):

- GEDI: the L1B layout (:mod:`canopyblocks.outputs.h5_gedi_l1b`) with the truth in
  ``BEAMxxxx/canopyblocks_truth/``; report: ``gedi_truth.csv`` and
  ``gedi_round_trip.csv`` (the L2A-style processing of the file against the truth).
- ESFL: ``cubes`` (footprints, rows, cols, bins) float32, ``top`` (footprints,) the
  elevation of bin 0's centre (bin k is centred k bins lower), ``x``/``y`` footprint
  centres (the tiles' CRS, attribute ``crs``; attribute ``along``: the track's unit vector),
  ``truth/ground``, ``truth/top``, ``truth/height``; attributes ``bin_size``,
  ``pixel_size``, ``footprint``, ``noise`` (sd per pixel and bin as a share of the mean
  brightest-pixel peak), ``vertical_datum`` (the tiles'), ``sensor = "esfl"``.
- dual: ``visible``, ``nir`` (footprints, bins) float32, ``top``, ``x``/``y``,
  ``noise_mean_visible|nir``, ``noise_sd_visible|nir``, ``truth/ground``,
  ``truth/cover``; attributes ``bin_size``, ``noise`` (sd as a share of the near-infrared
  peak), ``vertical_datum`` (the tiles'), ``sensor = "dual"``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..atomic import atomic_output
from ..errors import InputError
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from ..reference.dual_reference import DualFormParams, dual_bands, dual_noise_sd
from ..reference.footprint_returns import footprint_returns
from .dual_pairs import DualPairs
from .flash_cubes import FlashSimParams, simulate_flash_cubes, threshold_study
from .tracks import SimTrack, shots_along

__all__ = ["DualAlsParams", "simulate_dual_over_points", "simulate_esfl_to_file",
           "simulate_dual_to_file", "simulate_gedi_to_file", "gedi_round_trip",
           "simulate_sensor_over_tiles", "SENSOR_REACH_M"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DualAlsParams:
    """Dual-wavelength footprints over an airborne cloud (metres unless stated).

    Class 2 points reflect like soil, the others like leaves (visible, near infrared);
    points are weighted by a Gaussian footprint (``sigma``) and by 1 / (points in their
    1.5 m cell), so survey density does not count (DESIGN 4.9). ``noise``: sd as a share
    of the near-infrared peak (the dual-wavelength paper's 5 % by default; 0: noise free,
    the ground finder then gets a floor of 0.25 % of each band's peak).
    """

    # the formation's own defaults (one place: the dual-wavelength reference's)
    sigma: float = DualFormParams.sigma
    spacing: float = 10.0
    bin_size: float = DualFormParams.bin_size
    pulse_sigma: float = DualFormParams.pulse_sigma
    leaf: tuple[float, float] = DualFormParams.leaf
    soil: tuple[float, float] = DualFormParams.soil
    noise: float = DualFormParams.noise
    density_cell: float = DualFormParams.density_cell

    @property
    def formation(self) -> DualFormParams:
        """The pairs' formation: the dual-wavelength reference's parameters."""
        return DualFormParams(sigma=self.sigma, bin_size=self.bin_size,
                              pulse_sigma=self.pulse_sigma, leaf=self.leaf, soil=self.soil,
                              noise=self.noise, density_cell=self.density_cell)

    def __post_init__(self) -> None:
        if not self.spacing > 0:
            raise InputError(f"spacing must be positive, got {self.spacing!r}")
        _ = self.formation  # the formation's checks (sigma, bin_size, pulse_sigma, ..., noise)


def simulate_dual_over_points(points: LasPoints, track: SimTrack,
                              params: DualAlsParams | None = None, *, seed: int = 0
                              ) -> tuple[DualPairs, np.ndarray, np.ndarray]:
    """Visible/NIR pairs along ``track``; returns the pairs and the footprint centres."""
    p = params or DualAlsParams()
    sx, sy, _ = shots_along(track, p.spacing)
    ret = footprint_returns(points, sx, sy, p.sigma, density_cell=p.density_cell)
    n, shot, z, w, ground, r2 = ret.n, ret.shot, ret.z, ret.weight, ret.ground, ret.r2
    # the formation the dual-wavelength reference reads without noise (one function)
    top, _, bands = dual_bands(ret, p.formation)
    rng = np.random.default_rng(seed)
    sds = dual_noise_sd(bands, p.noise)
    out = [b + rng.normal(0, 1, b.shape) * sds[1][:, None] if p.noise > 0 else b
           for b in bands]
    wg = np.bincount(shot[ground], weights=w[ground], minlength=n)
    zg = np.bincount(shot[ground], weights=(w * z)[ground], minlength=n)
    wt = np.bincount(shot, weights=w, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(wg > 0, zg / wg, np.nan)
        cover = np.where(wt > 0, 1 - wg / wt, np.nan)
    hi = np.full(n, -np.inf)
    lo = np.full(n, np.inf)
    near = ground & (r2 <= (2 * p.sigma) ** 2)
    np.maximum.at(hi, shot[near], z[near])
    np.minimum.at(lo, shot[near], z[near])
    zeros = np.zeros(n)
    pairs_out = DualPairs(top, p.bin_size, out[0], out[1], (zeros, zeros.copy()), sds, g,
                          np.where(np.isfinite(hi), hi, np.nan),
                          np.where(np.isfinite(lo), lo, np.nan), cover)
    return pairs_out, sx, sy


def _h5():  # noqa: ANN202
    import h5py

    return h5py


def simulate_esfl_to_file(points: LasPoints, track: SimTrack, path: str | os.PathLike[str],
                          *, params: FlashSimParams | None = None, seed: int = 0,
                          report_dir: str | os.PathLike[str] | None = None,
                          progress: Progress | None = None) -> dict[str, object]:
    """Simulate ESFL cubes along ``track`` and write them (and the threshold study)."""
    prog = as_progress(progress)
    p = params or FlashSimParams()
    prog.update(0.0, "simulating flash cubes")
    sim = simulate_flash_cubes(points, track, p, seed=seed)
    prog.update(0.5, "writing")
    h5py = _h5()
    out = Path(path)
    with atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        f.attrs.update({"sensor": "esfl", "bin_size": p.bin_size, "pixel_size": p.pixel_size,
                        "footprint": p.footprint, "crs": str(points.crs),
                        "vertical_datum": str(points.vertical_datum), "noise": p.noise_sd,
                        "along": np.asarray(sim.along, float)})
        f.create_dataset("cubes", data=sim.cubes.astype(np.float32), compression="gzip")
        for k in ("top", "x", "y"):
            f.create_dataset(k, data=np.asarray(getattr(sim, k), float))
        for k in ("ground", "top", "height"):
            f.create_dataset(f"truth/{k}", data=sim.truth[f"truth_{k}"].to_numpy(float))
    summary: dict[str, object] = {"footprints": int(sim.cubes.shape[0]), "output": str(out)}
    if report_dir is not None:
        prog.update(0.7, "threshold study")
        table = threshold_study(sim, points)
        _write_report_table(table, Path(report_dir) / "esfl_threshold_study.csv")
        summary["study"] = table
    prog.report(1.0, "done")
    return summary


def simulate_dual_to_file(points: LasPoints, track: SimTrack, path: str | os.PathLike[str],
                          *, params: DualAlsParams | None = None, seed: int = 0,
                          report_dir: str | os.PathLike[str] | None = None,
                          progress: Progress | None = None) -> dict[str, object]:
    """Simulate dual-wavelength pairs along ``track`` and write them (and the study)."""
    from ..waveforms.dual_wavelength import dual_wavelength_ground
    from .dual_pairs import lowest_mode_ground

    prog = as_progress(progress)
    prog.update(0.0, "simulating dual-wavelength pairs")
    d, sx, sy = simulate_dual_over_points(points, track, params, seed=seed)
    h5py = _h5()
    out = Path(path)
    with atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        f.attrs.update({"sensor": "dual", "bin_size": d.bin_size, "crs": str(points.crs),
                        "vertical_datum": str(points.vertical_datum),
                        "noise": float((params or DualAlsParams()).noise)})
        f.create_dataset("visible", data=d.visible.astype(np.float32), compression="gzip")
        f.create_dataset("nir", data=d.nir.astype(np.float32), compression="gzip")
        for k, v in (("top", d.top), ("x", sx), ("y", sy),
                     ("noise_mean_visible", d.noise_mean[0]), ("noise_mean_nir", d.noise_mean[1]),
                     ("noise_sd_visible", d.noise_sd[0]), ("noise_sd_nir", d.noise_sd[1]),
                     ("truth/ground", d.ground_centre), ("truth/cover", d.cover)):
            f.create_dataset(k, data=np.broadcast_to(np.asarray(v, float), (len(d.top),)))
    summary: dict[str, object] = {"footprints": len(d.top), "output": str(out)}
    if report_dir is not None:
        prog.update(0.6, "ground study")
        g = dual_wavelength_ground(d.visible, d.nir, noise_mean=d.noise_mean,
                                   noise_sd=d.noise_sd)
        table = pd.DataFrame({"x": sx, "y": sy, "truth_ground": d.ground_centre,
                              "truth_cover": d.cover,
                              "dual_ground": d.position_to_elevation(g.centre),
                              "dual_tree_height": g.tree_height(d.bin_size),
                              "lowest_mode_ground": lowest_mode_ground(d)})
        table["dual_error"] = table["dual_ground"] - table["truth_ground"]
        table["mode_error"] = table["lowest_mode_ground"] - table["truth_ground"]
        _write_report_table(table, Path(report_dir) / "dual_ground_by_footprint.csv")
        summary["study"] = table
    prog.report(1.0, "done")
    return summary


#: The GEDI round trip's comparisons: metric, processed column, truth column, which truth.
GEDI_ROUND_TRIP = (
    ("ground", "ground", "truth_ground", "class-2 mean"),
    ("ground", "ground", "truth_ground_lowest_mode", "lowest mode"),
    ("rh50", "rh50", "truth_rh50", "class-2 mean"),
    ("rh50", "rh50", "truth_rh50_lowest_mode", "lowest mode"),
    ("rh98", "rh98", "truth_rh98", "class-2 mean"),
    ("rh98", "rh98", "truth_rh98_lowest_mode", "lowest mode"),
    ("cover", "cover", "truth_cover", "returns > 2 m above ground"),
    ("cover", "cover", "truth_cover_waveform", "noise-free waveform"),
)


def gedi_round_trip(path: str | os.PathLike[str], truth: pd.DataFrame) -> pd.DataFrame:
    """Read a simulated L1B back, process it (setting a1) and compare with the truth:
    per metric and truth ``n``, ``bias``, ``rmse`` (m; cover as a fraction).

    ``truth`` says which truth a row uses: ``class-2 mean`` (the weighted mean of the
    ground points; RH above it), ``lowest mode`` (the lowest mode of the noise-free
    waveform; RH above it: what ``run`` and ``validate`` compare footprints with),
    ``returns > 2 m above ground`` (cover as a fraction: the weighted share of returns more
    than 2 m above the ground) or ``noise-free waveform`` (cover of the noise-free
    waveform as the processing reads it: ``run``'s reference)."""
    from ..readers.gedi import gedi_beams, read_gedi_l1b
    from ..waveforms.process import process_waveforms

    beam = gedi_beams(path)[0]
    res = process_waveforms(read_gedi_l1b(path, beam))
    ok = (res["flag"] == "ok").to_numpy()
    rows = []
    for metric, ours, ref, which in GEDI_ROUND_TRIP:
        if ref not in truth.columns:
            continue
        d = res[ours].to_numpy(float) - truth[ref].to_numpy(float)
        d = d[ok & np.isfinite(d)]
        rows.append({"metric": metric, "truth": which, "n": int(d.size),
                     "bias": float(d.mean()) if d.size else np.nan,
                     "rmse": float(np.sqrt(np.mean(d * d))) if d.size else np.nan})
    return pd.DataFrame(rows)


def simulate_gedi_to_file(points: LasPoints, track: SimTrack, path: str | os.PathLike[str],
                          *, params: object = None, seed: int = 0,
                          report_dir: str | os.PathLike[str] | None = None,
                          progress: Progress | None = None) -> dict[str, object]:
    """Simulate GEDI waveforms along ``track``, write them in the L1B layout (and the
    truth and round-trip tables into ``report_dir``)."""
    from ..outputs.h5_gedi_l1b import write_gedi_l1b
    from .gedi_waveforms import GediSimParams, simulate_gedi

    prog = as_progress(progress)
    p = params if params is not None else GediSimParams()
    if not isinstance(p, GediSimParams):
        raise InputError(f"params must be GediSimParams; got {type(p).__name__}")
    prog.update(0.0, "simulating GEDI waveforms")
    sim = simulate_gedi(points, track, params=p, seed=seed)
    prog.update(0.6, "writing")
    out = write_gedi_l1b(path, [sim.batch], truth={sim.batch.beam: sim.truth},
                         attrs={"simulated": "canopyblocks GEDI waveform simulation",
                                "crs": sim.crs, "vertical_datum": sim.vertical_datum,
                                "seed": int(seed)})
    summary: dict[str, object] = {"footprints": len(sim.truth), "output": str(out)}
    if report_dir is not None:
        prog.update(0.8, "round trip")
        _write_report_table(sim.truth, Path(report_dir) / "gedi_truth.csv")
        table = gedi_round_trip(out, sim.truth)
        _write_report_table(table, Path(report_dir) / "gedi_round_trip.csv")
        summary["study"] = table
    prog.report(1.0, "done")
    return summary


def _write_report_table(table: pd.DataFrame, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        table.to_csv(tmp, index=False, float_format="%.4f")


#: Half-width of the corridor each sensor's footprints reach (3 sigma + 1 m), metres.
SENSOR_REACH_M = {"gedi": 17.5, "esfl": 10.0, "dual": 17.5}


def simulate_sensor_over_tiles(las_paths: list[str | os.PathLike[str]], sensor: str,
                               path: str | os.PathLike[str], *,
                               track: SimTrack | None = None, azimuth: float = 0.0,
                               centre: tuple[float, float] | None = None, seed: int = 0,
                               crs: str | int | None = None,
                               report_dir: str | os.PathLike[str] | None = None,
                               params: object = None, progress: Progress | None = None
                               ) -> tuple[SimTrack, dict[str, object]]:
    """GEDI, ESFL flash or dual-wavelength waveforms simulated over airborne tiles, as a file.

    The one entry point of ``canopyblocks simulate --sensor gedi|esfl|dual`` and of the
    QGIS algorithm: the track (``track``, or a line at ``azimuth`` degrees through the tiles'
    extent or ``centre``), only the corridor the footprints reach read from the tiles, then
    (with the sensor's parameters ``params``, e.g. ``GediSimParams(spacing=30.0)``)
    :func:`simulate_gedi_to_file` / :func:`simulate_esfl_to_file` /
    :func:`simulate_dual_to_file`.

    Returns
    -------
    (SimTrack, dict)
        The track used and the writer's summary.

    Raises
    ------
    InputError
        Unknown sensor, an output not named ``*.h5``, a negative seed.
    """
    from ..readers.las import las_bounds, read_las
    from .tracks import line_through  # noqa: PLC0415

    if sensor not in SENSOR_REACH_M:
        raise InputError(f"sensor {sensor!r} is not one of {', '.join(SENSOR_REACH_M)}")
    out = Path(path)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"output {out}: a {sensor} simulation is written as HDF5; name it *.h5")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise InputError(f"seed must be an integer >= 0; got {seed!r}")
    prog = as_progress(progress)
    reach = SENSOR_REACH_M[sensor]
    if track is None:
        track = line_through(las_bounds(list(las_paths)), float(azimuth), inset=reach,
                             centre=centre)
    vx, vy = zip(*track.vertices)
    bbox = (min(vx) - reach, min(vy) - reach, max(vx) + reach, max(vy) + reach)
    pts = read_las(list(las_paths), crs=crs, bbox=bbox, progress=prog.sub(0.0, 0.2))
    run = {"gedi": simulate_gedi_to_file, "esfl": simulate_esfl_to_file,
           "dual": simulate_dual_to_file}[sensor]
    summary = run(pts, track, out, seed=int(seed), report_dir=report_dir,  # type: ignore[operator]
                  params=params, progress=prog.sub(0.2, 1.0))
    return track, summary
