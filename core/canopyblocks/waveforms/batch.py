"""The one in-memory form of received waveforms: a batch of shots of one beam.

Readers (GEDI L1B, the waveform simulator's files) produce :class:`WaveformBatch`;
every processing step in :mod:`canopyblocks.waveforms` takes one and works on its
2-D ``waveforms`` array (shots x samples) without a Python loop over samples.

Conventions
-----------
- Sample ``j`` (0-based) of shot ``i`` lies at elevation
  ``elev_bin0[i] + j * (elev_lastbin[i] - elev_bin0[i]) / (n_samples[i] - 1)``
  (metres, the product's vertical datum: WGS84 ellipsoid for GEDI). Sample 0 is the
  *highest* (first received) sample; elevation decreases with the sample index.
- Shots have different lengths: ``waveforms`` is padded to the longest shot of the
  batch; padding samples (``j >= n_samples[i]``) hold that shot's ``noise_mean`` so
  that smoothing near the end does not invent signal. ``sample_mask()`` tells them apart.
- ``shot_number`` is uint64 and exact: join products on it, never through a float.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from ..errors import InputError

__all__ = ["WaveformBatch"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class WaveformBatch:
    """Received waveforms of ``n`` shots of one beam.

    Attributes
    ----------
    beam : str
        Beam name, e.g. ``"BEAM0101"``.
    shot_number : ndarray of uint64, shape (n,)
    time : ndarray of float64, shape (n,)
        The product's ``delta_time`` (s).
    waveforms : ndarray of float32, shape (n, m)
        Received waveform samples (digitiser counts), padded as described above.
    n_samples : ndarray of int64, shape (n,)
        Valid samples of each shot (``rx_sample_count``).
    elev_bin0, elev_lastbin : ndarray of float64, shape (n,)
        Elevation (m) of the first and the last valid sample.
    lat_bin0, lat_lastbin, lon_bin0, lon_lastbin : ndarray of float64, shape (n,)
        Geolocation (degrees WGS84) of the first and the last valid sample.
    noise_mean, noise_sd : ndarray of float64, shape (n,)
        Noise statistics of the raw waveform (GEDI ``noise_mean_corrected``,
        ``noise_stddev_corrected``), counts.
    stale, degraded : ndarray of bool, shape (n,)
        GEDI ``stale_return_flag != 0`` and ``geolocation/degrade != 0``.
    power : str
        ``"full"`` or ``"coverage"`` (or ``""`` when unknown).
    source : str
        Path of the file the batch came from.
    extra : dict of str to ndarray
        Further per-shot columns (e.g. simulation truth), each of shape (n,).
    """

    beam: str
    shot_number: npt.NDArray[np.uint64]
    time: FloatArray
    waveforms: npt.NDArray[np.float32]
    n_samples: npt.NDArray[np.int64]
    elev_bin0: FloatArray
    elev_lastbin: FloatArray
    lat_bin0: FloatArray
    lat_lastbin: FloatArray
    lon_bin0: FloatArray
    lon_lastbin: FloatArray
    noise_mean: FloatArray
    noise_sd: FloatArray
    stale: npt.NDArray[np.bool_]
    degraded: npt.NDArray[np.bool_]
    power: str = ""
    source: str = ""
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    _PER_SHOT = ("shot_number", "time", "n_samples", "elev_bin0", "elev_lastbin",
                 "lat_bin0", "lat_lastbin", "lon_bin0", "lon_lastbin", "noise_mean",
                 "noise_sd", "stale", "degraded")

    _DTYPES = {"shot_number": np.uint64, "waveforms": np.float32, "n_samples": np.int64,
               "stale": np.bool_, "degraded": np.bool_}

    def __post_init__(self) -> None:
        if not isinstance(self.beam, str):
            raise InputError(f"WaveformBatch.beam must be a beam name (str); got "
                             f"{type(self.beam).__name__}")
        if not isinstance(self.extra, dict):
            raise InputError(f"WaveformBatch.extra must be a dict of per-shot arrays; got "
                             f"{type(self.extra).__name__}")
        for name in ("waveforms", *self._PER_SHOT):  # lists become arrays of the field's type
            value = getattr(self, name)
            if isinstance(value, np.ndarray):
                continue
            if value is None or isinstance(value, (str, bytes, dict)):
                raise InputError(f"WaveformBatch.{name} must be an array of numbers; got "
                                 f"{type(value).__name__}")
            try:
                arr = np.asarray(value, dtype=self._DTYPES.get(name, np.float64))
            except (TypeError, ValueError, OverflowError):
                raise InputError(f"WaveformBatch.{name} must be an array of numbers; got "
                                 f"{type(value).__name__} {str(value)[:40]}") from None
            object.__setattr__(self, name, arr)
        if self.waveforms.ndim != 2:
            raise InputError(
                f"waveforms must be a 2-D array (shots x samples); got shape {self.waveforms.shape}")
        n = self.waveforms.shape[0]
        for name in self._PER_SHOT:
            arr = getattr(self, name)
            if np.shape(arr) != (n,):
                raise InputError(
                    f"WaveformBatch.{name} must have shape ({n},) like the waveforms; "
                    f"got {np.shape(arr)}")
        for name, arr in self.extra.items():
            if np.shape(arr) != (n,):
                raise InputError(f"WaveformBatch.extra[{name!r}] must have shape ({n},); "
                                 f"got {np.shape(arr)}")
        if n and (self.n_samples.max(initial=0) > self.waveforms.shape[1]):
            raise InputError("WaveformBatch.n_samples exceeds the waveform array's width")

    def __len__(self) -> int:
        return int(self.waveforms.shape[0])

    def sample_mask(self) -> npt.NDArray[np.bool_]:
        """Boolean (n, m): True where a sample is real, False where it is padding."""
        m = self.waveforms.shape[1]
        return np.arange(m)[None, :] < self.n_samples[:, None]

    def _fraction(self, pos: npt.ArrayLike) -> FloatArray:
        p = np.asarray(pos, dtype=np.float64)
        denom = np.maximum(self.n_samples - 1, 1).astype(np.float64)
        return p / denom

    def elevation(self, pos: npt.ArrayLike) -> FloatArray:
        """Elevation (m) at fractional sample positions ``pos`` (shape (n,), 0-based)."""
        t = self._fraction(pos)
        return self.elev_bin0 + t * (self.elev_lastbin - self.elev_bin0)

    def lonlat(self, pos: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Longitude and latitude (degrees) at fractional sample positions ``pos``."""
        t = self._fraction(pos)
        lon = self.lon_bin0 + t * (self.lon_lastbin - self.lon_bin0)
        lat = self.lat_bin0 + t * (self.lat_lastbin - self.lat_bin0)
        return lon, lat

    def sample_spacing(self) -> FloatArray:
        """Vertical distance between consecutive samples (m, positive), shape (n,)."""
        denom = np.maximum(self.n_samples - 1, 1).astype(np.float64)
        return np.abs(self.elev_bin0 - self.elev_lastbin) / denom

    def subset(self, mask: npt.ArrayLike) -> WaveformBatch:
        """The shots selected by a boolean mask or an index array."""
        sel = np.asarray(mask)
        kw = {name: getattr(self, name)[sel] for name in self._PER_SHOT}
        wf = self.waveforms[sel]
        width = int(kw["n_samples"].max(initial=0)) if len(wf) else 0
        return WaveformBatch(
            beam=self.beam, waveforms=wf[:, :max(width, 1)] if len(wf) else wf[:, :0],
            power=self.power, source=self.source,
            extra={k: v[sel] for k, v in self.extra.items()}, **kw)
