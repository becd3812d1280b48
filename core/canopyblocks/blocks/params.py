"""Parameters of the block engine (DESIGN.md section 1), validated once.

:class:`BlockParams` is a frozen dataclass; everything the engine needs to trust is
checked in ``__post_init__`` and bad values raise
:class:`~canopyblocks.errors.InputError` naming the allowed range and the value
received.  The engine does not re-check.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal, TypeGuard, cast

import numpy as np

from ..errors import InputError

__all__ = [
    "BlockParams",
    "CutoffSpec",
    "DEFAULT_CUTOFFS",
    "default_cutoffs",
    "NOISE_METHODS",
]

log = logging.getLogger(__name__)

NoiseMethod = Literal["sigma", "none"]
NOISE_METHODS: tuple[str, ...] = ("sigma", "none")

#: Paper cut-offs (seed 001 section 2.3, DESIGN 1.7): block length (m) -> (top, ground)
#: fractions of a block's kept photons.  The 10 m top follows the calibration sentence (5 %).
DEFAULT_CUTOFFS: dict[float, tuple[float, float]] = {
    10.0: (0.05, 0.075),
    25.0: (0.10, 0.20),
    50.0: (0.10, 0.25),
}

#: A cut-off given by the user: one fraction for every length, or length -> fraction.
CutoffSpec = float | Mapping[float, float] | tuple[tuple[float, float], ...] | None

#: A cut-off after validation (what ``BlockParams.__post_init__`` stores).
_NormalCutoff = float | tuple[tuple[float, float], ...] | None

#: A real number as accepted for a parameter (bools excluded by :func:`_is_number`).
_Number = int | float | np.integer | np.floating


def default_cutoffs(length: float) -> tuple[float, float]:
    """Paper (top, ground) cut-off fractions for a block ``length`` in metres.

    10, 25 and 50 m take the paper's values; other lengths interpolate linearly in
    the length, and lengths outside 10..50 m take the value of the nearer end
    (clamped), e.g. 100 m -> (0.10, 0.25), 5 m -> (0.05, 0.075).
    """
    from ..arguments import check_number
    check_number(length, "default_cutoffs: length", above=0.0, unit=" m")
    ls = np.array(sorted(DEFAULT_CUTOFFS))
    tops = np.array([DEFAULT_CUTOFFS[v][0] for v in ls])
    grounds = np.array([DEFAULT_CUTOFFS[v][1] for v in ls])
    return float(np.interp(length, ls, tops)), float(np.interp(length, ls, grounds))


def _is_number(v: object) -> TypeGuard[_Number]:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _fraction(v: object, what: str) -> float:
    if _is_number(v) and 0.0 < float(v) < 1.0:
        return float(v)
    raise InputError(f"{what} must be a fraction in (0, 1) (e.g. 0.1 for 10 %); got {v!r}")


def _positive(v: object, what: str, unit: str = "m") -> float:
    if _is_number(v) and math.isfinite(float(v)) and float(v) > 0:
        return float(v)
    raise InputError(f"{what} must be a positive finite number ({unit}); got {v!r}")


def _same_length(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)


@dataclass(frozen=True)
class BlockParams:
    """Parameters of :func:`~canopyblocks.blocks.compute_blocks`.

    Parameters
    ----------
    lengths : tuple of float
        Block lengths along the track, metres, each > 0; several lengths are
        computed in one run (a single number is accepted and becomes a 1-tuple).
        The paper used 50, 25 and 10 m.
    s0 : float or None
        Along-track origin of block 0, metres (same axis as ``PhotonTrack.s``).
        None: the track start (the smallest ``s``).  Photons with ``s < s0`` lie in
        no block.
    k_sigma : float
        Noise filter half-width in standard deviations (paper: 2.5).
    bin_size : float
        Histogram bin height, metres (paper: 0.5).
    window : float
        Initial expansion-window height, metres (paper: 2.0); must be a whole
        number of bins (``window / bin_size`` an integer >= 1).
    top_cutoff, ground_cutoff : float, mapping or None
        Fractions of a block's kept photons at which the top/ground window stops.
        None: the paper's defaults by length (:func:`default_cutoffs`).  A float
        applies to every length; a mapping ``{length: fraction}`` must name every
        length in ``lengths`` (it is stored as a sorted tuple of pairs so the
        parameters stay hashable).
    min_photons : int
        Blocks with fewer kept photons are flagged ``sparse`` (metrics NaN).
    noise : {"sigma", "none"}
        ``"sigma"``: the paper's ``|z - mean| <= k_sigma * std`` filter per block;
        ``"none"``: keep every photon.
    min_signal_conf : int or None
        ATL03 only: before the noise filter keep photons whose land
        ``signal_conf_ph >= min_signal_conf`` (-2..4).  None: no such filter (the
        paper's behaviour).
    """

    lengths: tuple[float, ...] = (25.0,)
    s0: float | None = None
    k_sigma: float = 2.5
    bin_size: float = 0.5
    window: float = 2.0
    top_cutoff: CutoffSpec = None
    ground_cutoff: CutoffSpec = None
    min_photons: int = 10
    noise: NoiseMethod = "sigma"
    min_signal_conf: int | None = None

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)
        set_ = object.__setattr__
        # lengths
        raw: object = self.lengths
        if _is_number(raw):
            raw = (raw,)
        try:
            if not isinstance(raw, Iterable):
                raise TypeError
            seq = tuple(raw)
        except TypeError:
            raise InputError(
                f"lengths must be a positive number or a sequence of them (m); got {raw!r}"
            ) from None
        if not seq:
            raise InputError("lengths is empty: give at least one block length in metres, e.g. 25")
        lengths = tuple(_positive(v, "block length") for v in seq)
        for i, a in enumerate(lengths):
            if any(_same_length(a, b) for b in lengths[:i]):
                raise InputError(f"block length {a} m is given twice in lengths={seq!r}")
        set_(self, "lengths", lengths)
        # origin
        if self.s0 is not None:
            if not _is_number(self.s0) or not math.isfinite(float(self.s0)):
                raise InputError(f"s0 must be None or a finite along-track distance (m); "
                                 f"got {self.s0!r}")
            set_(self, "s0", float(self.s0))
        set_(self, "k_sigma", _positive(self.k_sigma, "k_sigma", "standard deviations"))
        set_(self, "bin_size", _positive(self.bin_size, "bin_size"))
        set_(self, "window", _positive(self.window, "window"))
        ratio = self.window / self.bin_size
        if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio) or round(ratio) < 1:
            raise InputError(
                f"window ({self.window} m) must be a whole number (>= 1) of bins of "
                f"bin_size {self.bin_size} m; got {ratio:g} bins"
            )
        # cut-offs
        set_(self, "top_cutoff", self._cutoff_spec(self.top_cutoff, "top_cutoff"))
        set_(self, "ground_cutoff", self._cutoff_spec(self.ground_cutoff, "ground_cutoff"))
        # counts and options
        mp = self.min_photons
        if not isinstance(mp, (int, np.integer)) or isinstance(mp, bool) or mp < 1:
            raise InputError(f"min_photons must be an integer >= 1; got {mp!r}")
        set_(self, "min_photons", int(mp))
        if self.noise not in NOISE_METHODS:
            raise InputError(f"noise must be one of {NOISE_METHODS}; got {self.noise!r}")
        msc = self.min_signal_conf
        if msc is not None:
            if (not isinstance(msc, (int, np.integer)) or isinstance(msc, bool)
                    or not -2 <= msc <= 4):
                raise InputError(
                    f"min_signal_conf must be None or an integer from -2 to 4 (ATL03 "
                    f"signal_conf_ph); got {msc!r}"
                )
            set_(self, "min_signal_conf", int(msc))

    def _cutoff_spec(self, spec: object, what: str
                     ) -> float | tuple[tuple[float, float], ...] | None:
        if spec is None:
            return None
        if _is_number(spec):
            return _fraction(spec, what)
        if isinstance(spec, Mapping):
            items = list(spec.items())
        elif isinstance(spec, tuple) and all(isinstance(p, tuple) and len(p) == 2 for p in spec):
            items = list(spec)
        else:
            raise InputError(
                f"{what} must be None, a fraction in (0, 1), or a mapping "
                f"{{length_m: fraction}}; got {spec!r}"
            )
        pairs = tuple(sorted(
            (_positive(k, f"{what} length"), _fraction(v, f"{what}[{k}]")) for k, v in items
        ))
        for length in self.lengths:
            if not any(_same_length(length, k) for k, _ in pairs):
                raise InputError(
                    f"{what} gives no value for block length {length} m; it names "
                    f"{[k for k, _ in pairs]}: add {length} or give one fraction for all lengths"
                )
        return pairs

    @property
    def window_bins(self) -> int:
        """Initial window height in bins (``window / bin_size``)."""
        return int(round(self.window / self.bin_size))

    def cutoffs_for(self, length: float) -> tuple[float, float]:
        """The (top, ground) cut-off fractions used for block ``length`` (m)."""
        top_d, ground_d = default_cutoffs(length)
        # __post_init__ has normalised both specs (_cutoff_spec): no mapping is left.
        top = cast(_NormalCutoff, self.top_cutoff)
        ground = cast(_NormalCutoff, self.ground_cutoff)
        return (self._lookup(top, length, top_d, "top_cutoff"),
                self._lookup(ground, length, ground_d, "ground_cutoff"))

    @staticmethod
    def _lookup(spec: _NormalCutoff, length: float, default: float, what: str) -> float:
        if spec is None:
            return default
        if isinstance(spec, float):
            return spec
        for k, v in spec:
            if _same_length(k, length):
                return float(v)
        raise InputError(f"{what} gives no value for block length {length} m")
