"""GEDI L1B damage for the bad-input corpus: geometry, sample pool, amplitudes, positions,
dataset shapes and types, derived from the real subset in ``tests/data/gedi``.

Each :class:`GediDamage` edits a copy of the L1B and says which shots of ``BEAM0101`` it
damaged (they must not come out ``ok``) or that only a refusal is right. The independent
check (:func:`check_footprints`) reads the official L2A of the same shots with plain
h5py: every ``ok`` footprint must agree with L2A (setting a1) -- a damaged shot read
upside down, from its neighbour's samples or at latitude 109 cannot.
"""

from __future__ import annotations

import shutil
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

BEAM = "BEAM0101"
L1B_ZIP = "gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip"
L2A_ZIP = "gedi/GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.zip"
#: ok footprints must agree with L2A a1 within these (the undamaged file: RMSE 0.01 m,
#: all within 0.10 m)
TOLERANCE_M = 0.15
TOLERANCE_DEG = 1e-4

Edit = Callable[[h5py.File], None]


@dataclass(frozen=True)
class GediDamage:
    """One way to damage the L1B (``shots``: indices in ``BEAM0101`` that must not be ok)."""

    name: str
    edit: Edit
    shots: tuple[int, ...] = ()
    refuse: bool = False
    needles: tuple[str, ...] = ()
    warn_words: tuple[str, ...] = ("invalid_shot",)
    beams: tuple[str, ...] | None = (BEAM,)   # None: every beam


def unzipped(data_file: Callable[[str], Path], folder: Path) -> tuple[Path, Path]:
    """The real L1B and L2A subsets, unzipped into ``folder`` once."""
    out = []
    for rel in (L1B_ZIP, L2A_ZIP):
        z = data_file(rel)
        with zipfile.ZipFile(z) as zf:
            name = zf.namelist()[0]
            target = folder / name
            if not target.exists():
                folder.mkdir(parents=True, exist_ok=True)
                zf.extract(name, folder)
        out.append(target)
    return out[0], out[1]


def damaged(src: Path, dst: Path, edit: Edit) -> Path:
    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


# ---- edits ---------------------------------------------------------------------------------------


def _set(name: str, i: int | slice, value: Any, beam: str = BEAM) -> Edit:
    def edit(f: h5py.File) -> None:
        a = f[f"{beam}/{name}"][()]
        a[i] = value
        f[f"{beam}/{name}"][()] = a
    return edit


def _add(name: str, i: int, delta: int) -> Edit:
    def edit(f: h5py.File) -> None:
        a = f[f"{BEAM}/{name}"][()].astype(np.int64)
        a[i] += delta
        f[f"{BEAM}/{name}"][()] = a.astype(f[f"{BEAM}/{name}"].dtype)
    return edit


def _add_float(name: str, i: int, delta: float) -> Edit:
    def edit(f: h5py.File) -> None:
        a = f[f"{BEAM}/{name}"][()]
        a[i] += delta
        f[f"{BEAM}/{name}"][()] = a
    return edit


def _same_shot_number(i: int, j: int) -> Edit:
    """Shot ``j`` carries shot ``i``'s number (a join by shot number pairs them wrongly)."""
    def edit(f: h5py.File) -> None:
        for name in ("shot_number", "geolocation/shot_number"):
            if f"{BEAM}/{name}" in f:
                a = f[f"{BEAM}/{name}"][()]
                a[j] = a[i]
                f[f"{BEAM}/{name}"][()] = a
    return edit


def _swap_elevations(sel: int | slice, equal: bool = False) -> Edit:
    def edit(f: h5py.File) -> None:
        g = f[f"{BEAM}/geolocation"]
        b0, b1 = g["elevation_bin0"][()], g["elevation_lastbin"][()]
        n0, n1 = b0.copy(), b1.copy()
        n0[sel], n1[sel] = (b0[sel], b0[sel]) if equal else (b1[sel], b0[sel])
        g["elevation_bin0"][()] = n0
        g["elevation_lastbin"][()] = n1
    return edit


def _swap_starts(i: int, j: int) -> Edit:
    def edit(f: h5py.File) -> None:
        a = f[f"{BEAM}/rx_sample_start_index"][()]
        a[i], a[j] = a[j], a[i]
        f[f"{BEAM}/rx_sample_start_index"][()] = a
    return edit


def _sample(i: int, offset: int, value: float) -> Edit:
    def edit(f: h5py.File) -> None:
        g = f[BEAM]
        k = int(g["rx_sample_start_index"][i] - g["rx_sample_start_index"][0]) + offset
        rx = g["rxwaveform"][()]
        rx[k] = value
        g["rxwaveform"][()] = rx
    return edit


def _every_beam_scaled(factor: float) -> Edit:
    def edit(f: h5py.File) -> None:
        for b in [k for k in f if k.startswith("BEAM")]:
            f[f"{b}/rxwaveform"][()] = f[f"{b}/rxwaveform"][()] * factor
    return edit


def _replace(name: str, make: Callable[[np.ndarray], np.ndarray]) -> Edit:
    def edit(f: h5py.File) -> None:
        a = f[f"{BEAM}/{name}"][()]
        del f[f"{BEAM}/{name}"]
        f[f"{BEAM}/{name}"] = make(a)
    return edit


def _drop(name: str, beam: str) -> Edit:
    def edit(f: h5py.File) -> None:
        del f[f"{beam}/{name}"]
    return edit


G = "geolocation/"
DAMAGES: tuple[GediDamage, ...] = (
    GediDamage("bin0-lastbin-swapped", _swap_elevations(5), (5,)),
    GediDamage("bin0-lastbin-equal", _swap_elevations(5, equal=True), (5,)),
    GediDamage("bin0-lastbin-swapped-3", _swap_elevations(slice(20, 23)), (20, 21, 22)),
    GediDamage("count-plus-1", _add("rx_sample_count", 5, 1), (5,)),
    GediDamage("count-plus-80", _add("rx_sample_count", 5, 80), (5,)),
    # one sample fewer on an 850-sample shot: spacing +0.07 %, inside the accepted range
    # (below the floor: the heights move by at most one sample, 0.15 m, which the L2A
    # check still holds the result to)
    GediDamage("count-minus-1", _add("rx_sample_count", 5, -1), (), warn_words=()),
    GediDamage("count-minus-3", _add("rx_sample_count", 5, -3), (5,)),
    GediDamage("count-minus-40", _add("rx_sample_count", 5, -40), (5,)),
    GediDamage("last-count-plus-1", _add("rx_sample_count", 72, 1), refuse=True,
               needles=("rx_sample_count", "rxwaveform")),
    # the first shot's index one too small: it (not the last shot, shifted by it) is named
    GediDamage("first-start-minus-1", _add("rx_sample_start_index", 0, -1), refuse=True,
               needles=("19640513500108370",)),
    GediDamage("start-back-300", _add("rx_sample_start_index", 6, -300), (6,)),
    GediDamage("start-forward-50", _add("rx_sample_start_index", 5, 50), (5,)),
    GediDamage("starts-swapped", _swap_starts(5, 6), (5, 6)),
    GediDamage("sample-1e6", _sample(5, 300, 1e6), (5,)),
    GediDamage("sample-minus-1e5", _sample(5, 300, -1e5), (5,)),
    GediDamage("sample-nan", _sample(5, 300, np.nan), (5,), warn_words=("no_signal",)),
    GediDamage("lat-200", _set(G + "latitude_bin0", 5, 200.0), (5,)),
    GediDamage("lon-400", _set(G + "longitude_lastbin", 5, 400.0), (5,)),
    GediDamage("lat-nan", _set(G + "latitude_lastbin", 5, np.nan), (5,)),
    # first and last sample kilometres apart: the interpolated footprint position invented
    GediDamage("lastbin-lat-far", _set(G + "latitude_lastbin", 5, -10.0), (5,)),
    GediDamage("bin0-lon-1km", _add_float(G + "longitude_bin0", 5, 0.01), (5,)),
    GediDamage("shot-number-duplicate", _same_shot_number(5, 6), (5, 6)),
    GediDamage("bin0-nan", _set(G + "elevation_bin0", 5, np.nan), (5,)),
    GediDamage("bin0-fill", _set(G + "elevation_bin0", 5, -9999.0), (5,)),
    GediDamage("lastbin-f32max", _set(G + "elevation_lastbin", 5,
                                      float(np.finfo(np.float32).max)), (5,)),
    GediDamage("bin0-100km", _set(G + "elevation_bin0", 5, 1e5), (5,)),
    GediDamage("bin0-shifted-100km", _set(G + "elevation_bin0", slice(None), 1e5),
               refuse=True, needles=("elevation", "position")),
    GediDamage("all-swapped", _swap_elevations(slice(None)), refuse=True,
               needles=("elevation_bin0", "bin spacing")),
    GediDamage("all-equal", _swap_elevations(slice(None), equal=True), refuse=True,
               needles=("bin spacing",)),
    GediDamage("rx-scaled-1000", _every_beam_scaled(1000.0), refuse=True,
               needles=("amplitude",), beams=None),
    GediDamage("count-all-1", _replace("rx_sample_count", lambda a: np.ones_like(a)),
               refuse=True, needles=("bin spacing",)),
    GediDamage("count-strings", _replace("rx_sample_count",
                                         lambda a: np.array([str(v) for v in a], "S8")),
               refuse=True, needles=("rx_sample_count",)),
    GediDamage("count-words", _replace("rx_sample_count",
                                       lambda a: np.array([b"many"] * a.size, "S8")),
               refuse=True, needles=("rx_sample_count",)),
    GediDamage("count-float", _replace("rx_sample_count", lambda a: a + 0.5),
               refuse=True, needles=("rx_sample_count",)),
    GediDamage("count-2d", _replace("rx_sample_count", lambda a: np.stack([a, a], 1)),
               refuse=True, needles=("rx_sample_count",)),
    GediDamage("start-strings", _replace("rx_sample_start_index",
                                         lambda a: np.array([str(v) for v in a], "S12")),
               refuse=True, needles=("rx_sample_start_index",)),
    GediDamage("rxwaveform-2d", _replace("rxwaveform",
                                         lambda a: a[: a.size // 2 * 2].reshape(-1, 2)),
               refuse=True, needles=("rxwaveform",)),
    GediDamage("rxwaveform-strings", _replace("rxwaveform",
                                              lambda a: a.astype("S12")),
               refuse=True, needles=("rxwaveform",)),
    GediDamage("bin0-strings", _replace(G + "elevation_bin0", lambda a: a.astype("S20")),
               refuse=True, needles=("elevation_bin0",)),
    GediDamage("beam-without-rxwaveform", _drop("rxwaveform", "BEAM0010"),
               warn_words=("rxwaveform",), beams=None),
)


# ---- the independent check -----------------------------------------------------------------------


def l2a_truth(l2a: Path) -> dict[int, tuple[float, float, float, float, float]]:
    """shot number -> (ground, rh98, top, lat, lon) of L2A setting a1, read with h5py."""
    out: dict[int, tuple[float, float, float, float, float]] = {}
    with h5py.File(l2a) as f:
        for b in [k for k in f if k.startswith("BEAM")]:
            g = f[b]
            sn = g["shot_number"][()]
            ground = g["geolocation/elev_lowestmode_a1"][()]
            rh98 = g["geolocation/rh_a1"][()][:, 98] / 100.0
            top = g["geolocation/elev_highestreturn_a1"][()]
            lat = g["geolocation/lat_lowestmode_a1"][()]
            lon = g["geolocation/lon_lowestmode_a1"][()]
            for k in range(sn.size):
                out[int(sn[k])] = (float(ground[k]), float(rh98[k]), float(top[k]),
                                   float(lat[k]), float(lon[k]))
    return out


def damaged_shot_numbers(l1b: Path, shots: tuple[int, ...]) -> set[int]:
    with h5py.File(l1b) as f:
        sn = f[f"{BEAM}/shot_number"][()]
    return {int(sn[i]) for i in shots}


def check_footprints(table: Any, truth: dict[int, tuple[float, ...]], bad: set[int]) -> None:
    """Damaged shots are not ``ok``; every ``ok`` shot agrees with L2A a1."""
    flags = dict(zip(table["shot_number"].astype("int64"), table["flag"]))
    wrong = [s for s in bad if flags.get(s) == "ok"]
    assert not wrong, f"damaged shots {wrong} came out ok"
    ok = table[table["flag"] == "ok"]
    assert len(ok) >= 1, "no ok footprint left"
    for r in ok.itertuples():
        t = truth.get(int(r.shot_number))
        assert t is not None, f"ok shot {r.shot_number} is not in L2A"
        got = (r.ground, r.rh98, r.top)
        assert all(abs(a - b) <= TOLERANCE_M for a, b in zip(got, t[:3])), \
            f"ok shot {r.shot_number}: ground/rh98/top {got} vs L2A {t[:3]}"
        assert abs(r.lat - t[3]) <= TOLERANCE_DEG and abs(r.lon - t[4]) <= TOLERANCE_DEG, \
            f"ok shot {r.shot_number}: at {r.lat}, {r.lon} vs L2A {t[3]}, {t[4]}"
