"""The generated bad-input corpus (issue 10): no silent wrong number, no traceback, no
partial file, no hang.

``tests/badinputs/make_corpus.py`` derives several hundred damaged inputs from the real
files in ``tests/data`` at test time.  Each case is fed to the reader / operation it
concerns (in-process API calls for most; the command line in-process through
``run_main`` for a sample, and as real subprocesses for a smaller sample) and must end
in one of:

* a result that an independent check confirms (the photons, points, rasters or
  residuals are recomputed here from the damaged file with plain h5py / laspy /
  rasterio, never with canopyblocks' own readers);
* a result that is flagged, with a warning (``warn_words``);
* a refusal: the project's own error, one line naming the file and the problem (exit 2
  on the command line), with no output and no ``*.part*`` file left behind.

Anything else fails: another exception (a traceback), a wrong or implausible number, a
misleading message, a left-over file, or exceeding the time limit of a case.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import subprocess
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from badinputs.api_corpus import RUNNERS as API_RUNNERS  # noqa: E402
from badinputs.copc_corpus import RUNNERS as COPC_RUNNERS  # noqa: E402
from badinputs.gedi_corpus import RUNNERS as GEDI_RUNNERS  # noqa: E402
from badinputs.issue29_corpus import RUNNERS as ISSUE29_RUNNERS  # noqa: E402
from badinputs.make_corpus import (  # noqa: E402
    SUBPROCESS_SAMPLE,
    Base,
    Case,
    all_cases,
)
from badinputs.odd_inputs_corpus import RUNNERS as ODD_RUNNERS  # noqa: E402
from badinputs.options_corpus import RUNNERS as OPTIONS_RUNNERS  # noqa: E402
from badinputs.survey_corpus import RUNNERS as SURVEY_RUNNERS  # noqa: E402
from badinputs.xfail import XFAIL  # noqa: E402
from canopyblocks.errors import CanopyBlocksError  # noqa: E402

CASE_SECONDS = 40  # per case; a PDAL case takes about a second
H_MIN, H_MAX = -1000.0, 9000.0  # metres: any land-surface photon lies in between
MAX_CANOPY = 150.0  # metres: taller than any tree


# ---- running a case ------------------------------------------------------------------------------


class CaseTimeout(BaseException):
    """A case ran longer than its time limit (a hang)."""


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    def on_alarm(signum: int, frame: object) -> None:
        raise CaseTimeout(f"no answer within {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(scope="session")
def base(tmp_path_factory: pytest.TempPathFactory, sample: Any) -> Base:
    return Base(sample, tmp_path_factory.mktemp("corpus_base"))


def part_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".part" in p.name]


def check_refusal(case: Case, inputs: dict[str, Any], message: str) -> None:
    """One line naming the file (or the parameter) and the problem, nothing misleading."""
    low = message.lower()
    assert "\n" not in message.strip(), f"not one line: {message!r}"
    assert "traceback" not in low, message
    name = inputs.get("name") or (Path(inputs["path"]).name if inputs.get("path") else None)
    if name:
        names = {str(name).lower()}
        if str(name).startswith("--"):  # an option may be named as its parameter
            bare = str(name)[2:].lower()
            names |= {bare, bare.replace("-", "_"), bare.replace("-", " ")}
        assert any(n in low for n in names), f"does not name {name}: {message}"
    if case.needles:
        assert any(n.lower() in low for n in case.needles), \
            f"does not say the problem (any of {case.needles}): {message}"
    for bad in case.forbidden:
        assert bad.lower() not in low, f"misleading ({bad!r}): {message}"
    assert len(message) < 1500, f"message of {len(message)} characters"
    assert not re.search(r"\d{25,}", message), f"absurd number in: {message}"


def warned(ws: list[str], words: tuple[str, ...]) -> bool:
    return any(w.lower() in m.lower() for m in ws for w in words)


# ---- independent truths ---------------------------------------------------------------------------


def atl03_truth(path: Path, beam: str, msc: int | None) -> dict[str, np.ndarray] | None:
    """The photons of ``beam`` that are usable, read with plain h5py; None if undecidable."""
    try:
        f = h5py.File(path, "r")
    except Exception:  # noqa: BLE001 - an unreadable file has no truth
        return None
    with f:
        try:
            hg, gg = f[f"{beam}/heights"], f[f"{beam}/geolocation"]
            cols = {k: np.asarray(hg[k][()], dtype=float) for k in
                    ("h_ph", "lat_ph", "lon_ph", "dist_ph_along", "delta_time")}
            seg_x = np.asarray(gg["segment_dist_x"][()], dtype=float)
            beg = np.asarray(gg["ph_index_beg"][()], dtype=float)
            cnt = np.asarray(gg["segment_ph_cnt"][()], dtype=float)
            conf = np.asarray(hg["signal_conf_ph"][()], dtype=float) if msc is not None \
                else None
        except Exception:  # noqa: BLE001
            return None
    n = cols["h_ph"].shape[0] if cols["h_ph"].ndim == 1 else -1
    if n < 0 or any(v.shape != (n,) for v in cols.values()):
        return None
    if not (seg_x.ndim == beg.ndim == cnt.ndim == 1 and seg_x.size == beg.size == cnt.size):
        return None
    if not (np.isfinite(beg).all() and np.isfinite(cnt).all()) or (cnt < 0).any():
        return None
    if conf is not None:
        if conf.ndim == 2 and conf.shape[0] == n:
            conf = conf[:, 0]
        if conf.shape != (n,):
            return None
    use = (cnt > 0) & (beg > 0)
    starts, counts, xs = beg[use].astype(np.int64) - 1, cnt[use].astype(np.int64), seg_x[use]
    if counts.size and (starts + counts).max() > n:
        return None
    if counts.size > 1 and np.any(starts[1:] < starts[:-1] + counts[:-1]):
        if counts.sum() != n:
            return None
        starts = np.cumsum(counts) - counts  # the clipping tool's off-by-one (see reader)
    sx = np.full(n, np.nan)
    for st, c, x in zip(starts, counts, xs):  # <= a few dozen segments
        sx[st:st + c] = x
    s = sx + cols["dist_ph_along"]
    lat, lon, h = cols["lat_ph"], cols["lon_ph"], cols["h_ph"]
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(h) & (h >= H_MIN) & (h <= H_MAX) & np.isfinite(lat)
              & (np.abs(lat) <= 90) & np.isfinite(lon) & (np.abs(lon) <= 180)
              & np.isfinite(s) & (np.abs(cols["dist_ph_along"]) <= 1000) & (np.abs(sx) < 5e7))
        if conf is not None:
            ok &= (conf >= msc) & (conf <= 4)
    return {"h": h[ok], "s": s[ok], "n": np.asarray(int(ok.sum()))}


def check_photons_against(truth: dict[str, np.ndarray], s: np.ndarray, h: np.ndarray,
                          time: np.ndarray | None = None) -> None:
    assert s.size >= 1, "accepted with no photon"
    if time is not None:  # a photon's time is not used for heights, but never a fill value
        t = np.asarray(time, float)
        with np.errstate(invalid="ignore"):
            bad = np.isfinite(t) & ~(np.abs(t) < 1e10) | np.isinf(t)
        assert not bad.any(), f"{int(bad.sum())} photons carry an impossible time {t[bad][:3]}"
    assert np.isfinite(s).all() and np.isfinite(h).all(), "non-finite s or h"
    assert s.size <= int(truth["n"]), f"{s.size} photons > {int(truth['n'])} usable"
    key = {(round(float(a), 2), round(float(b), 3)) for a, b in zip(truth["s"], truth["h"])}
    unknown = sum((round(float(a), 2), round(float(b), 3)) not in key for a, b in zip(s, h))
    assert unknown == 0, f"{unknown} photons that are not usable photons of the file"


def check_blocks_against(truth: dict[str, np.ndarray], blocks: Any) -> None:
    """Every 'ok' block lies within the usable photons of its along-track extent."""
    if len(blocks) == 0:
        return
    ok = blocks[blocks["flag"] == "ok"]
    for r in ok.itertuples():
        assert np.isfinite([r.s_start, r.s_end, r.top, r.ground, r.hmax]).all(), r
        assert r.block >= 0, f"block index {r.block}"
        assert abs((r.s_end - r.s_start) - r.length) < 1e-6, r
        inside = (truth["s"] >= r.s_start) & (truth["s"] < r.s_end)
        hs = truth["h"][inside]
        assert hs.size >= 1, f"'ok' block {r.block} holds no usable photon"
        assert 1 <= r.n_photons <= hs.size, (r.n_photons, hs.size)
        assert hs.min() - 0.51 <= r.ground <= r.top <= hs.max() + 0.51, \
            (r.block, r.ground, r.top, hs.min(), hs.max())
        assert 0.0 <= r.hmax <= MAX_CANOPY, f"'ok' block {r.block} with Hmax {r.hmax:.1f} m"


def atl08_expected(atl03: Path, atl08: Path, beam: str) -> dict[tuple[float, float], int] | None:
    """(delta_time, h) -> ATL08 class per ATL03 photon, joined here independently."""
    with h5py.File(atl03) as f:
        g = f[f"{beam}/geolocation"]
        seg, cnt = g["segment_id"][()], g["segment_ph_cnt"][()]
        t3 = f[f"{beam}/heights/delta_time"][()]
        h3 = f[f"{beam}/heights/h_ph"][()].astype(float)
    use = cnt > 0
    seg, cnt = seg[use], cnt[use]
    starts = np.cumsum(cnt) - cnt  # the vegr clip's counts tile its photons
    try:
        with h5py.File(atl08) as f:
            sp = f[f"{beam}/signal_photons"]
            s8 = np.asarray(sp["ph_segment_id"][()], np.int64)
            i8 = np.asarray(sp["classed_pc_indx"][()], np.int64)
            c8 = np.asarray(sp["classed_pc_flag"][()], np.int64)
            t8 = np.asarray(sp["delta_time"][()], float) if "delta_time" in sp else None
    except Exception:  # noqa: BLE001
        return None
    if not (s8.shape == i8.shape == c8.shape) or (t8 is not None and t8.shape != s8.shape):
        return None
    table = {}
    for k in range(s8.size):
        table[(int(s8[k]), int(i8[k]))] = k
    out: dict[tuple[float, float], int] = {}
    for sid, st, c in zip(seg, starts, cnt):
        for j in range(int(c)):
            row = int(st) + j
            k = table.get((int(sid), j + 1))
            cls = -1
            if k is not None and 0 <= c8[k] <= 4 and (
                    t8 is None or abs(t8[k] - t3[row]) <= 1e-6):
                cls = int(c8[k])
            out[(round(float(t3[row]), 7), round(float(h3[row]), 3))] = cls
    return out


# ---- runners (API) --------------------------------------------------------------------------------


def run_atl03(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import BlockParams, compute_blocks, read_atl03

    track = read_atl03(i["path"], i["beam"], min_signal_conf=i["min_signal_conf"])
    return track, compute_blocks(track, BlockParams(lengths=(25.0,)))


def check_atl03(case: Case, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    track, blocks = result
    truth = atl03_truth(i["path"], i["beam"], i["min_signal_conf"])
    assert truth is not None, "accepted a file whose photons cannot be read independently"
    check_photons_against(truth, track.s, track.h, track.time)
    check_blocks_against(truth, blocks)


def run_atl08(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import read_atl03

    original = atl08_expected(i["atl03"], i["original"], i["beam"])
    assert original is not None
    i["unclassified_in_original"] = sum(v == -1 for v in original.values())
    return read_atl03(i["atl03"], i["beam"], atl08=i["path"])


def check_atl08(case: Case, i: dict[str, Any], track: Any, ws: list[str]) -> None:
    expected = atl08_expected(i["atl03"], i["path"], i["beam"])
    assert expected is not None, "accepted an ATL08 file that cannot be read independently"
    got = np.asarray(track.classification)
    assert set(np.unique(got)) <= {-1, 0, 1, 2, 3, 4}, f"invalid classes {np.unique(got)}"
    want = np.array([expected.get((round(float(t), 7), round(float(h), 3)), -99)
                     for t, h in zip(track.time, track.h)])
    known = want != -99
    assert known.all(), "photons not in the ATL03 file"
    wrong = int(np.sum(got != want))
    assert wrong == 0, f"{wrong} photons with another class than the independent join"
    if (got >= 0).sum() == 0:
        assert warned(ws, ("join", "match", "classif", "atl08")), \
            "no photon classified and no warning"
    if case.warn_words and (want == -1).sum() > i["unclassified_in_original"]:
        assert warned(ws, case.warn_words), f"invalid classes dropped silently; warnings {ws}"


def run_las(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import read_las

    return read_las([i["path"]])


def check_las(case: Case, i: dict[str, Any], pts: Any, ws: list[str]) -> None:
    t = i["truth"]
    assert len(pts) == t["z"].size, f"{len(pts)} points, the file holds {t['z'].size}"
    for k, got in (("x", pts.x), ("y", pts.y), ("z", pts.z)):
        a, b = np.sort(np.asarray(got, float)), np.sort(t[k])
        assert np.allclose(a, b, atol=0.011), f"{k} differs from the points written"


def run_simulate(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons

    pts = read_las([i["path"]])
    track = line_through(pts.bounds, 0.0, inset=7.0)
    return simulate_photons(pts, track, SimParams(), realisations=2, seed=0)


def _cloud_z_range(t: dict[str, np.ndarray]) -> tuple[float, float]:
    keep = ~np.isin(t["c"], (7, 18))
    z = t["z"][keep] if keep.any() else t["z"]
    return float(z.min()), float(z.max())


def check_simulate(case: Case, i: dict[str, Any], sim: Any, ws: list[str]) -> None:
    lo, hi = _cloud_z_range(i["truth"])
    h = np.asarray(sim.photon_columns(0)["h"], float)
    assert h.size >= 1, "no photon simulated and no refusal"
    assert np.isfinite(h).all()
    assert lo - 1.5 <= h.min() and h.max() <= hi + 1.5, \
        f"photon heights {h.min():.1f}..{h.max():.1f} outside the cloud's {lo:.1f}..{hi:.1f} m"
    if case.warn_words:
        assert warned(ws, case.warn_words), f"no warning about {case.warn_words}: {ws}"


def run_rasters(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks.reference.rasters import make_reference_rasters

    return make_reference_rasters([i["path"]], folder / "rasters", resolution=2.0)


def check_rasters(case: Case, i: dict[str, Any], res: Any, ws: list[str]) -> None:
    import rasterio

    t = i["truth"]
    lo, hi = _cloud_z_range(t)
    g = t["c"] == 2
    ext = (t["x"].max() - t["x"].min(), t["y"].max() - t["y"].min())
    w_max, h_max = ext[0] / 2.0 + 3, ext[1] / 2.0 + 3
    out = {p.name for p in (i["folder"] / "rasters").iterdir()}
    assert out == {"dtm.tif", "dsm_max.tif", "dsm_p90.tif", "dtm_fill_mask.tif"}, out
    for p in (res.dtm, res.dsm_max, res.dsm_p90):
        with rasterio.open(p) as src:
            a = src.read(1, masked=True)
            assert src.nodata is not None, f"{p.name}: nodata not declared"
            assert src.width <= w_max and src.height <= h_max, (src.width, src.height)
            assert src.width >= w_max / 4 and src.height >= h_max / 4, \
                f"{p.name}: {src.width} x {src.height} cells for a {ext[0]:.0f} x {ext[1]:.0f} m tile"
        v = a.compressed()
        assert v.size >= 1, f"{p.name}: no valid cell"
        zlo, zhi = (float(t["z"][g].min()), float(t["z"][g].max())) if p.name == "dtm.tif" \
            and g.any() else (lo, hi)
        assert zlo - 0.6 <= v.min() and v.max() <= zhi + 0.6, \
            f"{p.name}: values {v.min():.2f}..{v.max():.2f} outside the points' {zlo:.2f}..{zhi:.2f}"
    if case.warn_words:
        assert warned(ws, case.warn_words), f"no warning about {case.warn_words}: {ws}"


def run_validate(i: dict[str, Any], folder: Path) -> Any:
    import geopandas as gpd

    from canopyblocks.validation.block_validation import validate_blocks

    blocks = gpd.read_file(i["blocks"], layer="blocks")
    r = i["rasters"]
    return validate_blocks(blocks, dtm=r["dtm"], dsm_max=r["dsm_max"], dsm_p90=r["dsm_p90"],
                           width=13.0, offset=0.0, photon_vertical_crs=blocks.crs)


def check_validation_table(res: Any, ranges: dict[str, tuple[float, float]],
                           ws: list[str]) -> None:
    used = res[res["use"].astype(bool)] if "use" in res.columns else res
    if len(used) == 0:
        assert warned(ws, ("no block", "none", "0 of", "nothing", "cover", "valid")), \
            f"no block validated and no warning: {ws}"
        return
    for col, key in (("ref_ground", "dtm"), ("ref_top", "dsm_max")):
        lo, hi = ranges[key]
        v = used[col].to_numpy(float)
        v = v[np.isfinite(v)]
        assert v.size == 0 or (lo - 0.6 <= v.min() and v.max() <= hi + 0.6), \
            f"{col} {v.min():.2f}..{v.max():.2f} outside the reference's {lo:.2f}..{hi:.2f} m"
    r = used["res_ground"].to_numpy(float)
    r = r[np.isfinite(r)]
    assert r.size == 0 or np.abs(r).max() < 50.0, f"ground residual {np.abs(r).max():.1f} m"


def check_validate(case: Case, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    check_validation_table(result.residuals, i["ranges"], ws)


def run_table(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import read_table

    return read_table(i["path"])


def check_table(case: Case, i: dict[str, Any], track: Any, ws: list[str]) -> None:
    import csv

    with i["path"].open() as fh:
        rows = list(csv.DictReader(fh))

    def num(v: str | None) -> float:
        try:
            return float(v) if v is not None else np.nan
        except ValueError:
            return np.nan

    h = np.array([num(r.get("h")) for r in rows])
    lat = np.array([num(r.get("lat")) for r in rows])
    lon = np.array([num(r.get("lon")) for r in rows])
    t = np.array([num(r.get("time")) for r in rows])
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(h) & (h >= H_MIN) & (h <= H_MAX) & (np.abs(lat) <= 90)
              & (np.abs(lon) <= 180) & np.isfinite(t))
    assert len(track) >= 1
    assert len(track) <= int(ok.sum()), f"{len(track)} photons > {int(ok.sum())} usable rows"
    key = {(round(float(a), 6), round(float(b), 3)) for a, b in zip(t[ok], h[ok])}
    bad = sum((round(float(a), 6), round(float(b), 3)) not in key
              for a, b in zip(track.time, track.h))
    assert bad == 0, f"{bad} photons that are not usable rows of the table"


def run_param(i: dict[str, Any], folder: Path) -> Any:
    """The bad-parameter calls; the simulator ones run in a memory-limited subprocess."""
    import geopandas as gpd

    from canopyblocks import BlockParams, compute_blocks, read_atl03, read_las
    from canopyblocks.validation.stats import error_stats
    from canopyblocks.workflows.blocks import blocks_from_file

    name = i["call"]
    vegr, conifer = i["vegr"], i["conifer"]
    calls: dict[str, Any] = {
        "compute_blocks-None": lambda: compute_blocks(None, BlockParams()),
        "compute_blocks-path": lambda: compute_blocks(str(vegr), BlockParams()),
        "compute_blocks-geodataframe": lambda: compute_blocks(
            gpd.GeoDataFrame({"h": [1.0]}, geometry=gpd.points_from_xy([0.0], [0.0])),
            BlockParams()),
        "read_atl03-None": lambda: read_atl03(None, "gt1r"),  # type: ignore[arg-type]
        "read_atl03-beam-int": lambda: read_atl03(vegr, 3),  # type: ignore[arg-type]
        "read_atl03-beam-unknown": lambda: read_atl03(vegr, "gt9x"),
        "blocks_from_file-beams-str": lambda: blocks_from_file(
            vegr, BlockParams(lengths=(25.0,)), beams="gt1r"),
        "blockparams-lengths-str": lambda: BlockParams(lengths="abc"),  # type: ignore[arg-type]
        "blockparams-lengths-zero": lambda: BlockParams(lengths=(0.0,)),
        "blockparams-lengths-negative": lambda: BlockParams(lengths=(-5.0,)),
        "blockparams-lengths-nan": lambda: BlockParams(lengths=(float("nan"),)),
        "blockparams-k-str": lambda: BlockParams(k_sigma="2"),  # type: ignore[arg-type]
        "blockparams-min-photons-negative": lambda: BlockParams(min_photons=-1),
        "blockparams-top-cutoff-2": lambda: BlockParams(top_cutoff=2.0),
        "error_stats-empty": lambda: error_stats(np.array([]), np.array([])),
        "read_las-None": lambda: read_las(None),  # type: ignore[arg-type]
        "read_las-empty-list": lambda: read_las([]),
        "read_las-text-file": lambda: read_las([_text_file(folder / "cloud.laz")]),
        "rasters-resolution-zero": lambda: _rasters(conifer, folder, 0.0),
        "rasters-resolution-nan": lambda: _rasters(conifer, folder, float("nan")),
        "rasters-resolution-tiny": lambda: _rasters(conifer, folder, 1e-4),
    }
    if name in calls:
        return calls[name]()
    return _isolated_simulation(name, conifer, folder)


def _text_file(p: Path) -> Path:
    p.write_text("not a point cloud\n")
    return p


def _rasters(tile: Path, folder: Path, resolution: float) -> Any:
    from canopyblocks.reference.rasters import make_reference_rasters

    return make_reference_rasters([tile], folder / "rasters", resolution=resolution)


_SIM_CALLS = {
    "simparams-shot-spacing-tiny": "SimParams(shot_spacing=1e-5)",
    "simparams-mean-photons-1e9": "SimParams(mean_photons=1e9)",
    "simparams-noise-rate-1e6": "SimParams(noise_rate=1e6)",
    "simulate-seed-negative": "SimParams(), seed=-1",
}


class Refused(CanopyBlocksError):
    """A refusal reported by an isolated subprocess."""


def _isolated_simulation(name: str, tile: Path, folder: Path) -> Any:
    """Run a simulation with absurd parameters in a subprocess limited to 3 GiB."""
    args = _SIM_CALLS[name]
    code = f"""
import sys, resource
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
from canopyblocks import read_las
from canopyblocks.errors import CanopyBlocksError
from canopyblocks.simulate import SimParams, line_through, simulate_photons
pts = read_las([{str(tile)!r}])
try:
    sim = simulate_photons(pts, line_through(pts.bounds, 0.0, inset=7.0), {args})
except CanopyBlocksError as exc:
    print("REFUSED:" + str(exc)); sys.exit(0)
print("OK:%d" % len(sim.photon_columns(0)["h"]))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=CASE_SECONDS, cwd=folder)
    assert r.returncode == 0, f"exit {r.returncode}: {r.stderr[-2000:]}"
    out = r.stdout.strip().splitlines()[-1]
    if out.startswith("REFUSED:"):
        raise Refused(out[len("REFUSED:"):])
    return out


def check_param(case: Case, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    if i["call"] == "blocks_from_file-beams-str":
        assert [t.track for t in result.tracks] == ["gt1r"], \
            f"beams='gt1r' read as {[t.track for t in result.tracks]}"
        return
    if i["call"] == "simulate-seed-negative":
        raise AssertionError(f"a negative seed was accepted ({result})")
    raise AssertionError(f"accepted: {result!r}")


def run_atl03_url(i: dict[str, Any], folder: Path) -> Any:
    """The damaged granule read from a loopback HTTP server (range requests); the check is
    the local file's (plain h5py)."""
    from loopback_servers import RangeHTTPServer

    p = Path(i["path"])
    with RangeHTTPServer(p.parent) as server:
        return run_atl03({**i, "path": f"{server.url}/{p.name}"}, folder)


RUNNERS = {"atl03": (run_atl03, check_atl03), "atl03-url": (run_atl03_url, check_atl03), "atl08": (run_atl08, check_atl08),
           "las": (run_las, check_las), "simulate": (run_simulate, check_simulate),
           "rasters": (run_rasters, check_rasters), "validate": (run_validate, check_validate),
           "table": (run_table, check_table), "param": (run_param, check_param)}
RUNNERS.update(GEDI_RUNNERS)  # damaged GEDI L1B files (badinputs/gedi_corpus.py)
RUNNERS.update(API_RUNNERS)  # misuse of every public function (badinputs/api_corpus.py)
RUNNERS.update(ISSUE29_RUNNERS)  # wrong background rates, foreign exceptions (issue 29)
RUNNERS.update(COPC_RUNNERS)  # damaged COPC files and EPT datasets (badinputs/copc_corpus.py)
RUNNERS.update(ODD_RUNNERS)  # ignored options, missing bckgrd_atlas, box reads
RUNNERS.update(SURVEY_RUNNERS)  # copies, lying headers, groundless tiles, mixed datums
RUNNERS.update(OPTIONS_RUNNERS)  # options that act or are refused, box context, network


def judge_api(case: Case, inputs: dict[str, Any], folder: Path) -> str:
    run, check = RUNNERS[case.runner]
    inputs["folder"] = folder
    with warnings.catch_warnings(record=True) as caught, time_limit(CASE_SECONDS):
        warnings.simplefilter("always")
        try:
            result = run(inputs, folder)
        except CanopyBlocksError as exc:
            assert not case.must_accept, f"an undamaged input was refused: {exc}"
            check_refusal(case, inputs, str(exc))
            assert part_files(folder) == [], part_files(folder)
            out = folder / "rasters"
            assert not out.exists() or not any(out.iterdir()), "outputs left after a refusal"
            return "refused"
    ws = [str(w.message) for w in caught]
    assert not case.must_refuse, "accepted; only a refusal is right"
    check(case, inputs, result, ws)
    assert part_files(folder) == [], part_files(folder)
    return "accepted"


# ---- the command line --------------------------------------------------------------------------------


def run_cli_inprocess(args: list[str]) -> tuple[int, str, str]:
    from canopyblocks.cli import cli
    from canopyblocks.cli.common import run_main

    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err), time_limit(CASE_SECONDS):
        warnings.simplefilter("default")  # what a user's interpreter does
        code = run_main(cli, args)
    return code, out.getvalue(), err.getvalue()


def run_cli_subprocess(args: list[str], folder: Path) -> tuple[int, str, str]:
    tmp = folder / "tmpdir"
    tmp.mkdir(exist_ok=True)
    env = dict(os.environ, TMPDIR=str(tmp), TMP=str(tmp), TEMP=str(tmp))
    r = subprocess.run([sys.executable, "-m", "canopyblocks", *args], capture_output=True,
                       text=True, timeout=120, env=env, cwd=folder,
                       preexec_fn=_limit_memory)
    assert list(tmp.iterdir()) == [], f"left in TMPDIR: {list(tmp.iterdir())}"
    return r.returncode, r.stdout, r.stderr


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))


def check_cli_outputs(case: Case, inputs: dict[str, Any], args: list[str]) -> None:
    """Re-check what an accepted command wrote with the independent checks."""
    import geopandas as gpd

    cmd = args[0]
    if cmd == "blocks":
        # the command keeps every photon and filters by confidence per block:
        # n_photons counts them all
        truth = atl03_truth(inputs["path"], inputs["beam"], None)
        assert truth is not None, "accepted a file whose photons cannot be read independently"
        check_blocks_against(truth, gpd.read_file(inputs["outputs"][0], layer="blocks"))
    elif cmd == "simulate" and inputs.get("truth") is not None:
        with h5py.File(inputs["outputs"][0]) as f:
            h = np.concatenate([f[f"{b}/heights/h_ph"][()] for b in f if b.startswith("gt")])
        lo, hi = _cloud_z_range(inputs["truth"])
        assert lo - 1.5 <= h.min() and h.max() <= hi + 1.5, \
            f"photon heights {h.min():.1f}..{h.max():.1f} outside {lo:.1f}..{hi:.1f} m"
    elif cmd == "validate":
        res = gpd.read_file(inputs["outputs"][0], layer="residuals")
        check_validation_table(res, inputs["ranges"], [])


def judge_cli(case: Case, inputs: dict[str, Any], folder: Path, subprocess_run: bool) -> str:
    args = inputs["args"]
    if subprocess_run:
        code, out, err = run_cli_subprocess(args, folder)
    else:
        code, out, err = run_cli_inprocess(args)
    assert "Traceback" not in err, err
    assert code in (0, 2), (code, err[-3000:])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert not any(re.search(r"\w+Warning: |\.py:\d+: ", ln) for ln in lines), \
        f"a raw Python warning reached the user: {err}"
    assert part_files(folder) == [], part_files(folder)
    warnings_ = [ln for ln in lines if ln.startswith("canopyblocks: warning:")]
    if code == 2:
        assert not case.must_accept, f"an undamaged input was refused: {err}"
        errors = [ln for ln in lines if ln.startswith("canopyblocks: error:")]
        assert len(errors) == 1 and lines[-1] == errors[0], err
        assert all(ln.startswith("canopyblocks: ") for ln in lines), err
        check_refusal(case, inputs, errors[0])
        for p in inputs["outputs"]:
            assert not Path(p).exists(), f"{p} left after exit 2"
        return "refused"
    assert not case.must_refuse, "accepted; only a refusal is right"
    for p in inputs["outputs"]:
        assert Path(p).exists(), f"exit 0 but {p} was not written"
    if case.warn_words:
        assert warned(warnings_, case.warn_words), f"no warning about {case.warn_words}: {err}"
    check_cli_outputs(case, inputs, args)
    return "accepted"


# ---- the test -------------------------------------------------------------------------------------------


def _params() -> list[Any]:
    out = []
    for c in all_cases():
        marks = [pytest.mark.xfail(strict=False, reason=XFAIL[c.id])] if c.id in XFAIL else []
        out.append(pytest.param(c, id=c.id, marks=marks))
        if c.id in SUBPROCESS_SAMPLE:
            out.append(pytest.param(c, id=f"{c.id}-subprocess", marks=marks))
    return out


@pytest.mark.parametrize("case", _params())
def test_corpus(case: Case, base: Base, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    if case.pdal:
        request.getfixturevalue("pdal_bin")  # skips (fails under CI=true) without PDAL
    inputs = case.make(tmp_path, base)
    if case.runner == "cli":
        outcome = judge_cli(case, inputs, tmp_path,
                            request.node.callspec.id.endswith("-subprocess"))
    else:
        outcome = judge_api(case, inputs, tmp_path)
    log = os.environ.get("CANOPYBLOCKS_CORPUS_LOG")  # for a tally of the outcomes
    if log:
        with open(log, "a") as fh:
            fh.write(f"{request.node.callspec.id}\t{outcome}\n")


def test_corpus_is_large_enough() -> None:
    cases = all_cases()
    assert len(cases) >= 300
    assert len({c.id for c in cases}) == len(cases)


# ---- messages and small traps of the command line -------------------------------------------------


def _quiet_args(name: str, base: Base, out: Path) -> list[str]:
    r = base.rasters["paths"]
    sim_blocks = base.folder / "blocks" / "sim_atl03.h5"
    base.blocks  # noqa: B018 - makes the simulated photons too
    return {
        "blocks": ["blocks", str(base.vegr), "-o", str(out / "b.gpkg"), "--length", "25",
                   "--preset", "icesat2", "--min-signal-conf", "2"],
        "rasters": ["rasters", str(base.conifer), "-o", str(out / "r"), "--resolution", "4"],
        "simulate": ["simulate", str(base.conifer), "--azimuth", "0", "--realisations", "2",
                     "-o", str(out / "s.h5")],
        "validate": ["validate", str(base.blocks), "--dtm", str(r["dtm"]), "--dsm-max",
                     str(r["dsm_max"]), "--dsm-p90", str(r["dsm_p90"]), "--offset", "0",
                     "--width", "13", "-o", str(out / "v.gpkg")],
        "calibrate": ["calibrate", str(sim_blocks), "--dtm", str(r["dtm"]), "--dsm-max",
                      str(r["dsm_max"]), "--dsm-p90", str(r["dsm_p90"]), "--offset", "0",
                      "--width", "13", "--crs", "EPSG:2949", "--length", "25",
                      "-o", str(out / "cal.csv")],
    }[name]


@pytest.mark.parametrize("command", [
    "blocks", pytest.param("rasters", marks=pytest.mark.pdal), "validate", "simulate",
    "calibrate"])
def test_quiet_prints_no_summaries(command, base, tmp_path, request) -> None:
    """``-q``: warnings and errors only; a successful run prints nothing else."""
    if command == "rasters":
        request.getfixturevalue("pdal_bin")
    code, out, err = run_cli_inprocess(["-q", *_quiet_args(command, base, tmp_path)])
    assert code == 0, err
    assert out.strip() == "", out
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert all(ln.startswith("canopyblocks: warning:") for ln in lines), err


def test_validate_csv_output_names_the_files_written(base, tmp_path) -> None:
    r = base.rasters["paths"]
    out = tmp_path / "v.csv"
    code, _, err = run_cli_inprocess([
        "validate", str(base.blocks), "--dtm", str(r["dtm"]), "--dsm-max", str(r["dsm_max"]),
        "--dsm-p90", str(r["dsm_p90"]), "--offset", "0", "--width", "13", "-o", str(out)])
    assert code == 0, err
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == ["v_residuals.csv", "v_stats.csv"], written
    for name in written:
        assert name in err, err
    assert f"-> {out}" not in err, f"names a file it did not write: {err}"


def test_validate_onto_its_own_geopackage_keeps_the_blocks(base, tmp_path) -> None:
    """``validate X.gpkg -o X.gpkg``: refused, or the blocks layer survives beside the new ones."""
    import shutil

    import geopandas as gpd
    import pyogrio

    src = tmp_path / "blocks.gpkg"
    shutil.copyfile(base.blocks, src)
    before = gpd.read_file(src, layer="blocks")
    r = base.rasters["paths"]
    code, _, err = run_cli_inprocess([
        "validate", str(src), "--dtm", str(r["dtm"]), "--dsm-max", str(r["dsm_max"]),
        "--dsm-p90", str(r["dsm_p90"]), "--offset", "0", "--width", "13", "-o", str(src)])
    assert code in (0, 2), err
    assert "blocks" in [n for n, _ in pyogrio.list_layers(src)]
    after = gpd.read_file(src, layer="blocks")
    assert len(after) == len(before) and after["top"].equals(before["top"])
    if code == 2:
        assert len([ln for ln in err.splitlines() if ln.strip()]) == 1, err
    assert part_files(tmp_path) == []
