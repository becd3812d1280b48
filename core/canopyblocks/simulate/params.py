"""Parameters of the photon simulator (DESIGN.md section 3, seed 002), validated once."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from ..errors import InputError

__all__ = [
    "SimParams",
    "TruthParams",
    "POISSON_MEANS",
    "INSTRUMENTS",
    "Instrument",
    "Ecosystem",
    "Beam",
    "SPEED_OF_LIGHT",
    "PHOTONS_PER_SHOT_PER_M_PER_MHZ",
    "BACKGROUND_PRESETS_MHZ",
]

Instrument = Literal["icesat2", "mabel"]
Ecosystem = Literal["boreal", "temperate", "tropical"]
Beam = Literal["strong", "weak"]

#: Mean signal photons per shot of the strong beam (seed 002 table 1).
POISSON_MEANS: dict[str, float] = {"boreal": 1.0, "temperate": 1.9, "tropical": 0.6}

#: Weak beam energy relative to the strong beam (seed 002: 4:1 ratio).
WEAK_BEAM_RATIO = 0.25

#: Speed of light in vacuum, m/s.
SPEED_OF_LIGHT = 299_792_458.0

#: Background photons per shot per metre of height window for a rate of 1 MHz: a window
#: ``dh`` metres tall lasts ``2 dh / c`` seconds of two-way travel, so a rate ``r``
#: (photons/s) gives ``r * 2 / c`` photons per shot per metre (1 MHz = 0.00667).
PHOTONS_PER_SHOT_PER_M_PER_MHZ = 1e6 * 2.0 / SPEED_OF_LIGHT

#: Background rates (MHz) of the ``night`` and ``day`` presets: ICESat-2 night-time
#: rates are ~0.1-0.3 MHz, daytime ~1-5 MHz (the bundled real daytime clip: 0.9-3.7 MHz).
BACKGROUND_PRESETS_MHZ: dict[str, float] = {"night": 0.15, "day": 3.0}
#: Background rates (MHz) at or above this are refused: ATL03 readers take them for damage.
MAX_BACKGROUND_MHZ = 1000.0
#: Largest telemetry half-height (m) simulated: real bands are tens to hundreds of metres.
MAX_TELEMETRY_WINDOW_M = 3000.0

#: Instrument presets: footprint diameter (m), shot spacing (m), pulse rate (Hz).
#: ICESat-2: 13 m at the start of the mission (17 m at the end), 0.7 m, 10 kHz.
#: MABEL: ~2 m footprint, 5 kHz at ~200 m/s aircraft speed = 0.04 m.
INSTRUMENTS: dict[str, tuple[float, float, float]] = {
    "icesat2": (13.0, 0.7, 10_000.0),
    "mabel": (2.0, 0.04, 5_000.0),
}


def _positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise InputError(f"{name} must be a positive number of metres; got {value!r}")


@dataclass(frozen=True)
class TruthParams:
    """How truth is read from each footprint's pseudo-waveform (see ``truth.py``).

    Attributes
    ----------
    bin_size : float
        Pseudo-waveform bin, metres (default 0.1 m).
    peak_fraction : float
        A local maximum counts as a peak when its amplitude is at least this fraction
        of the waveform's highest amplitude (0..1, default 0.05); the ground is the
        lowest such peak.
    rh_floor : float or None
        RH metrics use the weighted returns more than this many metres above the
        ground; None = 2 x PSF sigma (0.5 m for 0.25 m).
    cover_threshold : float
        Canopy returns for canopy cover are those more than this many metres above the
        ground (default 2 m).
    """

    bin_size: float = 0.1
    peak_fraction: float = 0.05
    rh_floor: float | None = None
    cover_threshold: float = 2.0

    def __post_init__(self) -> None:
        _positive("bin_size", self.bin_size)
        if not (0.0 < self.peak_fraction < 1.0):
            raise InputError(f"peak_fraction must be in (0, 1); got {self.peak_fraction!r}")
        if self.rh_floor is not None and not (math.isfinite(self.rh_floor) and self.rh_floor >= 0):
            raise InputError(f"rh_floor must be >= 0 metres or None; got {self.rh_floor!r}")
        if not (math.isfinite(self.cover_threshold) and self.cover_threshold >= 0):
            raise InputError(f"cover_threshold must be >= 0 metres; got {self.cover_threshold!r}")


@dataclass(frozen=True)
class SimParams:
    """Parameters of one simulation.

    Attributes
    ----------
    instrument : "icesat2" or "mabel"
        Sets the defaults of ``diameter``, ``shot_spacing`` and ``pulse_rate``.
    diameter : float or None
        Footprint diameter, metres (ICESat-2: 13 at the start of the mission, 17 at
        the end); weights ``exp(-2 r^2 / R^2)`` with ``R = diameter / 2`` (1/e^2 at R).
    shot_spacing : float or None
        Distance between footprint centres along the track, metres (0.7 for ICESat-2).
    pulse_rate : float or None
        Shots per second; photon ``time`` = shot index / pulse_rate (seconds).
    photon_rate : "boreal", "temperate" or "tropical"
        The ecosystem photon rate: Poisson mean of signal photons per strong-beam shot
        (1.0, 1.9, 0.6); ignored when ``mean_photons`` is given.
    preset : str or None
        Deprecated spelling of ``photon_rate`` (warns; then set to None).
    beam : "strong" or "weak"
        The weak beam gets a quarter of the strong beam's mean.
    mean_photons : float or None
        User Poisson mean per shot (for the chosen beam), overriding photon_rate/beam.
    psf : float
        Instrument point-spread (Gaussian sigma), metres (ATLAS: 0.25).
    background_rate_mhz : float
        Solar background rate, MHz (10^6 photons per second), the same for strong and
        weak beams (0 = off, the default; seed 002 lists noise as future work). Night
        ~0.1-0.3, day ~1-5 (:data:`BACKGROUND_PRESETS_MHZ`). Background photons fall
        uniformly in the telemetry window, ``rate x 2 / c`` per shot per metre of it.
    noise_rate : float or None
        Deprecated spelling of the background rate in photons per shot per metre of
        window (1 MHz = 0.00667); converted to ``background_rate_mhz`` and then set
        to None (so ``dataclasses.replace`` with a new rate works);
        :attr:`noise_per_shot_per_m` gives the per-shot-per-metre rate.
    telemetry_window : float
        Half-height of the telemetry window, metres: background photons fall between
        ``coarse terrain - telemetry_window`` and ``coarse terrain + telemetry_window``
        (default 100 m, a 200 m tall window; real ATL03 windows over land are tens to
        hundreds of metres tall). It knows nothing of the footprints' canopy.
    telemetry_smoothing : float
        Scale of the coarse terrain the window follows, metres (default 1000): the
        airborne ground points (class 2; the lowest point per cell when the cloud has
        no ground class) smoothed along the track with a Gaussian of standard deviation
        ``telemetry_smoothing / 4``, as ATL03 sets its window from a coarse DEM.
    geolocation_sigma : float
        Horizontal geolocation error: each shot's reported position is moved by a
        Gaussian of this sigma (metres) in x and y; 0 = exact footprint centre.
    exclude_classes : tuple of int
        ASPRS classes ignored in the airborne cloud (default noise 7 and 18).
    truth : TruthParams
        How truth is read from the pseudo-waveform.
    """

    instrument: Instrument = "icesat2"
    diameter: float | None = None
    shot_spacing: float | None = None
    pulse_rate: float | None = None
    photon_rate: Ecosystem = "temperate"
    beam: Beam = "strong"
    mean_photons: float | None = None
    psf: float = 0.25
    background_rate_mhz: float = 0.0
    noise_rate: float | None = None
    telemetry_window: float = 100.0
    telemetry_smoothing: float = 1000.0
    geolocation_sigma: float = 0.0
    exclude_classes: tuple[int, ...] = (7, 18)
    truth: TruthParams = field(default_factory=TruthParams)
    preset: Ecosystem | None = None

    def __post_init__(self) -> None:
        if self.preset is not None:  # the old name of the photon rate
            from ..errors import warn_renamed
            warn_renamed("SimParams(preset=)", "SimParams(photon_rate=)", stacklevel=4)
            if not isinstance(self.preset, str) or self.preset not in POISSON_MEANS:
                raise InputError(f"preset (the old name of photon_rate) must be one of "
                                 f"{', '.join(POISSON_MEANS)}; got {self.preset!r}")
            object.__setattr__(self, "photon_rate", self.preset)
            object.__setattr__(self, "preset", None)
        from ..arguments import check_fields
        check_fields(self)
        if self.instrument not in INSTRUMENTS:
            raise InputError(
                f"instrument must be one of {', '.join(INSTRUMENTS)}; got {self.instrument!r}")
        d, sp, rate = INSTRUMENTS[self.instrument]
        if self.diameter is None:
            object.__setattr__(self, "diameter", d)
        if self.shot_spacing is None:
            object.__setattr__(self, "shot_spacing", sp)
        if self.pulse_rate is None:
            object.__setattr__(self, "pulse_rate", rate)
        _positive("diameter", float(self.diameter))  # type: ignore[arg-type]
        _positive("shot_spacing", float(self.shot_spacing))  # type: ignore[arg-type]
        _positive("pulse_rate", float(self.pulse_rate))  # type: ignore[arg-type]
        _positive("psf", self.psf)
        if self.photon_rate not in POISSON_MEANS:
            raise InputError(f"photon_rate must be one of {', '.join(POISSON_MEANS)}; got "
                             f"{self.photon_rate!r}")
        if self.beam not in ("strong", "weak"):
            raise InputError(f"beam must be 'strong' or 'weak'; got {self.beam!r}")
        if self.mean_photons is not None and not (
                math.isfinite(self.mean_photons) and self.mean_photons >= 0):
            raise InputError(
                f"mean_photons must be >= 0 photons per shot; got {self.mean_photons!r}")
        self._check_background()
        if not (math.isfinite(self.geolocation_sigma) and self.geolocation_sigma >= 0):
            raise InputError(
                f"geolocation_sigma must be >= 0 metres; got {self.geolocation_sigma!r}")
        if not isinstance(self.truth, TruthParams):
            raise InputError("truth must be a TruthParams")
        object.__setattr__(self, "exclude_classes", tuple(int(c) for c in self.exclude_classes))

    def _check_background(self) -> None:
        """Validate the background rate (MHz or the deprecated per-shot-per-metre form)
        and the telemetry window; fill both rate spellings."""
        mhz = self.background_rate_mhz
        if not (isinstance(mhz, (int, float)) and math.isfinite(mhz) and mhz >= 0):
            raise InputError(f"background_rate_mhz must be >= 0 MHz (night ~0.15, day ~3); "
                             f"got {mhz!r}")
        nr = self.noise_rate
        if nr is not None:
            if not (isinstance(nr, (int, float)) and math.isfinite(nr) and nr >= 0):
                raise InputError(f"noise_rate must be >= 0 photons per shot per metre "
                                 f"(deprecated: use background_rate_mhz); got {nr!r}")
            from_nr = float(nr) / PHOTONS_PER_SHOT_PER_M_PER_MHZ
            if mhz > 0 and not math.isclose(from_nr, mhz, rel_tol=1e-9):
                raise InputError(
                    f"give the background rate once: background_rate_mhz={mhz!r} and "
                    f"noise_rate={nr!r} (= {from_nr:.4g} MHz) disagree")
            mhz = from_nr
        if mhz >= MAX_BACKGROUND_MHZ:
            given = (f"noise_rate={nr!r} photons per shot per metre (= {mhz:.4g} MHz)"
                     if nr is not None else
                     f"background_rate_mhz (--background-rate) {mhz:g} MHz")
            raise InputError(
                f"{given}: ATL03 readers take a background rate of {MAX_BACKGROUND_MHZ:g} "
                "MHz (1 GHz) or more for damage, and the brightest sunlit scenes give ~10 "
                "MHz; give a rate below that (day ~3)")
        object.__setattr__(self, "background_rate_mhz", float(mhz))
        object.__setattr__(self, "noise_rate", None)
        for name in ("telemetry_window", "telemetry_smoothing"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number of metres; got {v!r}")
        if self.telemetry_window > MAX_TELEMETRY_WINDOW_M:
            raise InputError(
                f"telemetry_window (--telemetry-window) {self.telemetry_window:g} m: the "
                f"half-height of ATL03's telemetry band is tens to hundreds of metres; give "
                f"at most {MAX_TELEMETRY_WINDOW_M:g} m")

    @property
    def noise_per_shot_per_m(self) -> float:
        """Mean background photons per shot per metre of telemetry window."""
        return self.background_rate_mhz * PHOTONS_PER_SHOT_PER_M_PER_MHZ

    @property
    def radius(self) -> float:
        """Footprint radius R = diameter / 2, metres."""
        return float(self.diameter) / 2.0  # type: ignore[arg-type]

    @property
    def photon_mean(self) -> float:
        """Poisson mean of signal photons per shot for this beam."""
        if self.mean_photons is not None:
            return float(self.mean_photons)
        m = POISSON_MEANS[self.photon_rate]
        return m * WEAK_BEAM_RATIO if self.beam == "weak" else m

    @property
    def rh_floor(self) -> float:
        """Metres above ground from which returns count as canopy energy for RH metrics."""
        return 2.0 * self.psf if self.truth.rh_floor is None else float(self.truth.rh_floor)
