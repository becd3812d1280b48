"""Parameters of the GEDI L2A-style waveform processing (DESIGN 4.3, 4.5, 4.6).

The six L2A setting groups ``a1`` .. ``a6`` differ in three numbers, recorded by L2A
itself in ``rx_processing_aN/ancillary``: the front threshold ``k_f``
(``rx_front_threshold``), the back threshold ``k_b`` (``rx_back_threshold``), both in
noise standard deviations above the noise mean, and the smoothing width of the mode
search (``rx_smoothing_width_zcross``, samples). Everything else is shared, except that
a2 (``enable_select_mode`` = 1) does not take a weak last mode as the ground: its ground
is the lowest mode with at least ``cumulative_energy_thresh`` = 2.5 % of the signal
energy between it and the signal bottom (L2A's ``selected_mode``; found to reproduce
every a2 shot of the sample granule).

Smoothing kernels
-----------------
L2A smooths on a grid of 0.25 sample (``rx_subbin_resolution`` = 4): the waveform is
linearly interpolated 4x, then convolved with a Gaussian truncated at a few standard
deviations. DESIGN 4.3 states the kernel as "sd = the width, truncated at 2 sd". The
smoothed amplitudes L2A stores (``botloc_amp``, ``zcross_amp``, ``rx_modeamps`` of all
six groups in the sample granule) show that L2A's effective kernel is narrower at the
core than that: for width 6.5 samples a Gaussian of sd 6.0 samples truncated at 15
samples reproduces them, for width 3.5 a Gaussian of sd 3.125 truncated at 7.5 samples.
With the nominal kernel a1 still agrees with L2A to ~0.03 m RMSE, but about 30 % of
the modes move by a quarter sample and the 3.5-sample groups (a2, a3, a5, a6) lose
weak modes that L2A keeps (ground errors of metres in a5); with the calibrated kernel
every group reproduces L2A to ~0.01 m RMSE. ``kernel="l2a"`` (default) uses the
calibrated kernel for the widths L2A uses; ``kernel="nominal"`` uses the DESIGN 4.3
kernel for any width.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..errors import InputError

__all__ = [
    "Setting",
    "SETTINGS",
    "SETTING_NAMES",
    "KernelName",
    "L2A_KERNELS",
    "SettingGroup",
    "WaveformParams",
]

Setting = Literal["a1", "a2", "a3", "a4", "a5", "a6"]
KernelName = Literal["l2a", "nominal"]


@dataclass(frozen=True)
class SettingGroup:
    """One L2A setting group.

    Attributes
    ----------
    front_threshold : float
        ``k_f``: the signal top is where the smoothed waveform first exceeds
        ``noise_mean + k_f * noise_sd``.
    back_threshold : float
        ``k_b``: signal bottom and mode threshold, ``noise_mean + k_b * noise_sd``.
    mode_smoothing : float
        Gaussian smoothing width of the mode search and of the cumulative energy
        (samples).
    ground_min_energy : float
        Percent. When > 0, the ground is the lowest mode with at least this share of
        the signal energy between it and the signal bottom (L2A's mode selection,
        ``enable_select_mode`` with ``cumulative_energy_thresh``; a2: 2.5); when 0,
        the lowest mode.
    """

    front_threshold: float
    back_threshold: float
    mode_smoothing: float
    ground_min_energy: float = 0.0


#: The six L2A setting groups (values as L2A records them in ``rx_processing_aN/ancillary``).
SETTINGS: dict[str, SettingGroup] = {
    "a1": SettingGroup(3.0, 6.0, 6.5),
    "a2": SettingGroup(3.0, 3.0, 3.5, 2.5),
    "a3": SettingGroup(3.0, 6.0, 3.5),
    "a4": SettingGroup(6.0, 6.0, 6.5),
    "a5": SettingGroup(3.0, 2.0, 3.5),
    "a6": SettingGroup(3.0, 4.0, 3.5),
}
SETTING_NAMES: tuple[str, ...] = tuple(SETTINGS)

#: L2A's effective smoothing kernels on the 0.25-sample grid, by nominal width (samples):
#: (Gaussian sd, truncation half-width), both in sub-samples (quarter samples).
#: Identified from L2A's stored smoothed amplitudes; see the module docstring.
L2A_KERNELS: dict[float, tuple[float, int]] = {
    6.5: (24.0, 60),
    3.5: (12.5, 30),
}


@dataclass(frozen=True)
class WaveformParams:
    """Parameters of :func:`canopyblocks.waveforms.process.process_waveforms`.

    Parameters
    ----------
    setting : {"a1", "a2", "a3", "a4", "a5", "a6"}
        L2A setting group (thresholds and mode-search smoothing, see :data:`SETTINGS`).
    all_rh : bool
        Also return ``rh0`` .. ``rh100`` (every percent), not only the table's RH columns.
    decompose : bool
        Also run the Gaussian decomposition (DESIGN 4.4; column ``ground_gauss``).
    rho_ratio : float
        ``rho_v / rho_g`` of the cover formula (DESIGN 4.5); GEDI L2B uses 1.5.
    terrain_filter : bool
        Flag terrain outliers along each beam (GEDI criteria: :mod:`.gedi_outliers`).
    kernel : {"l2a", "nominal"}
        Smoothing kernel: L2A's effective kernel (default) or DESIGN 4.3's nominal
        Gaussian (sd = width, truncated at 2 sd).
    location_smoothing : float
        Smoothing width for the signal top and bottom (samples); L2A 6.5.
    preprocessor_threshold : float
        Raw samples above ``noise_mean + preprocessor_threshold * noise_sd`` bound the
        search window (L2A 4).
    search_size : int
        Samples added on either side of the first/last raw sample above the
        preprocessor threshold (L2A 100).
    max_modes : int
        Footprints with more modes are flagged ``too_many_modes`` (L2A 20).
    subsamples : int
        Sub-samples per sample of the smoothing grid (L2A 4).
    penetration_height : float
        Penetration = share of the energy returned from below ground + this (m; seed 003: 2).
    front_threshold, back_threshold, mode_smoothing : float, optional
        Override the setting group's ``k_f``, ``k_b`` and mode-search width.
    """

    setting: Setting = "a1"
    all_rh: bool = False
    decompose: bool = False
    rho_ratio: float = 1.5
    terrain_filter: bool = True
    kernel: KernelName = "l2a"
    location_smoothing: float = 6.5
    preprocessor_threshold: float = 4.0
    search_size: int = 100
    max_modes: int = 20
    subsamples: int = 4
    penetration_height: float = 2.0
    front_threshold: float | None = None
    back_threshold: float | None = None
    mode_smoothing: float | None = None

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)
        if self.setting not in SETTINGS:
            raise InputError(
                f"setting {self.setting!r} is not an L2A setting group; "
                f"use one of {', '.join(SETTING_NAMES)}")
        if self.kernel not in ("l2a", "nominal"):
            raise InputError(f"kernel {self.kernel!r} is not known; use 'l2a' or 'nominal'")
        for name in ("rho_ratio", "location_smoothing", "penetration_height"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise InputError(f"{name} must be a number > 0; got {value!r}")
        for name in ("front_threshold", "back_threshold", "mode_smoothing"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and value > 0):
                raise InputError(f"{name} must be a number > 0 (or None for the setting's "
                                 f"value); got {value!r}")
        if not (isinstance(self.preprocessor_threshold, (int, float))
                and self.preprocessor_threshold >= 0):
            raise InputError("preprocessor_threshold must be a number >= 0; "
                             f"got {self.preprocessor_threshold!r}")
        for name, low in (("search_size", 0), ("max_modes", 1), ("subsamples", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise InputError(f"{name} must be an integer >= {low}; got {value!r}")
        if self.kernel == "l2a":
            for width in (self.location_smoothing, self.group.mode_smoothing):
                if float(width) not in L2A_KERNELS:
                    raise InputError(
                        f"kernel='l2a' knows L2A's smoothing only for widths "
                        f"{', '.join(str(w) for w in L2A_KERNELS)} samples; got {width}; "
                        "use kernel='nominal' for other widths")
            if self.subsamples != 4:
                raise InputError(f"kernel='l2a' needs subsamples=4 (L2A's grid); got "
                                 f"{self.subsamples}; use kernel='nominal' for other grids")

    @property
    def group(self) -> SettingGroup:
        """The effective setting group (the named one with any overrides applied)."""
        base = SETTINGS[self.setting]
        return SettingGroup(
            float(self.front_threshold) if self.front_threshold is not None
            else base.front_threshold,
            float(self.back_threshold) if self.back_threshold is not None
            else base.back_threshold,
            float(self.mode_smoothing) if self.mode_smoothing is not None
            else base.mode_smoothing,
            base.ground_min_energy,
        )

    def kernel_shape(self, width: float) -> tuple[float, int]:
        """Gaussian sd and truncation half-width (both in sub-samples) for ``width`` samples."""
        if self.kernel == "l2a":
            return L2A_KERNELS[float(width)]
        sd = float(width) * self.subsamples
        return sd, int(2.0 * sd)
