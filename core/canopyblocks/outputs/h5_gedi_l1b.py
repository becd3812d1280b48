"""Write waveforms in the GEDI L1B layout (for the simulator and tests).

Any GEDI L1B reader opens the result: per beam ``BEAMxxxx`` (attribute ``description``)
the datasets ``rxwaveform`` (float32, all shots' samples end to end), ``rx_sample_count``
(uint16), ``rx_sample_start_index`` (uint64, 1-based), ``shot_number`` (uint64),
``delta_time``, ``noise_mean_corrected``, ``noise_stddev_corrected``,
``stale_return_flag`` (uint8), and ``geolocation/{elevation,latitude,longitude}_{bin0,
lastbin}``, ``geolocation/degrade`` (int8), ``geolocation/shot_number``; dtypes as in real
granules. Truth columns go to ``BEAMxxxx/canopyblocks_truth/<name>`` (not in real files);
the file's attributes say it is simulated and in which vertical datum its elevations are.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..atomic import atomic_output
from ..errors import InputError
from ..waveforms.batch import WaveformBatch

__all__ = ["write_gedi_l1b"]


def write_gedi_l1b(path: str | os.PathLike[str], batches: Sequence[WaveformBatch], *,
                   truth: Mapping[str, pd.DataFrame] | None = None,
                   attrs: Mapping[str, object] | None = None) -> Path:
    """Write one beam per batch in the L1B layout (atomically).

    Parameters
    ----------
    path : path
        Output ``.h5``.
    batches : sequence of WaveformBatch
        One per beam (distinct ``beam`` names).
    truth : mapping beam -> DataFrame, optional
        Per-shot columns written under ``BEAMxxxx/canopyblocks_truth/``.
    attrs : mapping, optional
        File attributes (e.g. ``crs``, ``vertical_datum``, ``simulated``).
    """
    import h5py

    names = [b.beam for b in batches]
    if len(set(names)) != len(names):
        raise InputError(f"one batch per beam; got beams {names}")
    out = Path(path)
    with atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        for b in batches:
            g = f.create_group(b.beam)
            g.attrs["description"] = np.array(
                ["Full power beam" if b.power == "full" else "Coverage beam"], dtype=object)
            mask = b.sample_mask()
            count = b.n_samples.astype(np.int64)
            wave = b.waveforms[mask].astype(np.float32)   # row-major: shot after shot
            starts = np.concatenate([[0], np.cumsum(count)[:-1]]) + 1
            g.create_dataset("rxwaveform", data=wave, chunks=(max(1, min(14200, wave.size)),)
                             if wave.size else None, compression="gzip" if wave.size else None)
            g.create_dataset("rx_sample_count", data=count.astype(np.uint16))
            g.create_dataset("rx_sample_start_index", data=starts.astype(np.uint64))
            g.create_dataset("shot_number", data=b.shot_number.astype(np.uint64))
            g.create_dataset("delta_time", data=np.asarray(b.time, np.float64))
            g.create_dataset("noise_mean_corrected", data=np.asarray(b.noise_mean, np.float64))
            g.create_dataset("noise_stddev_corrected", data=np.asarray(b.noise_sd, np.float64))
            g.create_dataset("stale_return_flag", data=b.stale.astype(np.uint8))
            geo = g.create_group("geolocation")
            for name, arr in (("elevation_bin0", b.elev_bin0),
                              ("elevation_lastbin", b.elev_lastbin),
                              ("latitude_bin0", b.lat_bin0), ("latitude_lastbin", b.lat_lastbin),
                              ("longitude_bin0", b.lon_bin0),
                              ("longitude_lastbin", b.lon_lastbin)):
                fill = np.where(np.isfinite(arr), arr, -9999.0)
                ds = geo.create_dataset(name, data=np.asarray(fill, np.float64))
                if name.startswith("elevation") and (attrs or {}).get("vertical_datum"):
                    vd = str((attrs or {})["vertical_datum"])   # a simulated file's datum
                    ds.attrs["units"] = "meters"
                    ds.attrs["vertical_crs"] = vd
                    ds.attrs["description"] = (
                        f"Elevation of the {name.split('_')[1]} sample in the vertical CRS "
                        f"{vd} (that of the airborne lidar it was simulated from)")
            geo.create_dataset("degrade", data=b.degraded.astype(np.int8))
            geo.create_dataset("shot_number", data=b.shot_number.astype(np.uint64))
            if truth is not None and b.beam in truth:
                t = truth[b.beam]
                if len(t) != len(b):
                    raise InputError(f"truth of {b.beam} has {len(t)} rows for {len(b)} shots")
                tg = g.create_group("canopyblocks_truth")
                for col in t.columns:
                    tg.create_dataset(col, data=t[col].to_numpy())
    return out
