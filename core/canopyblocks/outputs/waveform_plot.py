"""The waveform plot every GEDI user draws, and an HTML view of several shots.

Elevation on the vertical axis (as the ground sees it), counts on the horizontal: the raw
and smoothed waveform, the noise mean, the front and back thresholds, the modes, the
ground (lowest mode), the signal top and bottom, the RH25/50/75/98 heights, and fitted
Gaussians when the shot was decomposed. Plots are drawn from
:class:`~canopyblocks.waveforms.details.ShotDetails` only (no reprocessing here).
"""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_output
from ..waveforms.details import ShotDetails
from .plotting import new_figure, save_figure

__all__ = ["plot_waveform", "waveform_html", "plots_index", "WaveformMarkers", "waveform_markers",
           "elevation_datum"]

RH_MARKED: tuple[int, ...] = (25, 50, 75, 98)


@dataclass(frozen=True)
class WaveformMarkers:
    """Elevations (m) and counts the plot marks, for checks and for other front-ends."""

    ground: float
    top: float
    bottom: float
    modes: tuple[float, ...]
    rh_elevations: dict[int, float]
    noise_mean: float
    front_threshold: float
    back_threshold: float


def waveform_markers(d: ShotDetails) -> WaveformMarkers:
    """The positions :func:`plot_waveform` draws: RH_k at ground + RH_k."""
    rh = {k: float(d.ground + d.rh[k]) for k in RH_MARKED
          if k in d.rh and np.isfinite(d.rh[k]) and np.isfinite(d.ground)}
    return WaveformMarkers(float(d.ground), float(d.top), float(d.bottom),
                           tuple(float(m) for m in np.asarray(d.modes, float)), rh,
                           float(d.noise_mean), float(d.front_threshold),
                           float(d.back_threshold))


def elevation_datum(source: str | os.PathLike[str]) -> str:
    """The vertical datum of an L1B file's elevations, as the plot's axis names it: the
    WGS84 ellipsoid (GEDI), or the datum a simulated file states in its
    ``vertical_datum`` attribute (the airborne tiles' own, e.g. 'CGVD28 height')."""
    try:
        import pyproj

        from ..readers._h5 import open_h5

        with open_h5(source) as f:  # the one place h5py is touched
            attrs = f.attrs("/")
        stated = attrs.get("vertical_datum") if "simulated" in attrs else None
        if stated is None:
            return "WGS84 ellipsoid"
        crs = pyproj.CRS.from_user_input(stated.decode() if isinstance(stated, bytes)
                                         else str(stated))
    except Exception:  # not an HDF5 file or an unreadable datum: GEDI's own
        return "WGS84 ellipsoid"
    for sub in (crs.sub_crs_list if crs.is_compound else [crs]):
        if sub.is_vertical:
            return str(sub.name)
    return "WGS84 ellipsoid" if crs.to_epsg() == 4979 else str(crs.name)


def plot_waveform(details: ShotDetails, path: str | os.PathLike[str], *,
                  title: str | None = None, vertical_datum: str = "WGS84 ellipsoid") -> Path:
    """PNG of one processed shot (written atomically).

    Parameters
    ----------
    details : ShotDetails
        From :func:`canopyblocks.waveforms.process.shot_details`.
    path : path
        PNG to write.
    title : str, optional
        Default: beam, shot number, setting and flag.
    vertical_datum : str
        Named on the elevation axis (GEDI L1B elevations are WGS84 ellipsoidal).
    """
    d = details
    mk = waveform_markers(d)
    fig, ax = new_figure(figsize=(5.0, 7.0))
    ax.plot(d.raw, d.elevation, color="0.55", lw=0.8, label="raw")
    ax.plot(d.smoothed, d.smoothed_elevation, color="tab:blue", lw=1.4, label="smoothed")
    for value, style, label in ((mk.noise_mean, ":", "noise mean"),
                                (mk.front_threshold, "--", "front threshold"),
                                (mk.back_threshold, "-.", "back threshold")):
        if np.isfinite(value):
            ax.axvline(value, color="k", ls=style, lw=0.8, label=label)
    lo, hi = float(np.nanmin(d.raw)), float(np.nanmax(d.raw))
    if mk.modes:
        amp = np.interp(mk.modes, d.smoothed_elevation[::-1], d.smoothed[::-1])
        ax.scatter(amp, mk.modes, color="tab:orange", zorder=5, s=18, label="modes")
    for value, colour, label in ((mk.top, "tab:green", "signal top"),
                                 (mk.bottom, "tab:purple", "signal bottom"),
                                 (mk.ground, "tab:brown", "ground (lowest mode)")):
        if np.isfinite(value):  # left of the RH labels' column
            ax.hlines(value, lo - 0.05 * (hi - lo), hi, color=colour, lw=1.2, label=label)
    for k, z in mk.rh_elevations.items():  # the line stops where its label begins
        ax.hlines(z, lo - 0.05 * (hi - lo), hi, color="tab:red", lw=0.6, ls="--")
        ax.text(hi, z, f" RH{k} {d.rh[k]:.1f} m", va="center", ha="left", fontsize=7,
                color="tab:red", bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5})
    if d.gaussians is not None and len(d.gaussians):
        elev = np.asarray(d.elevation, float)
        for amp_g, centre, sigma in np.asarray(d.gaussians, float):
            ax.plot(d.noise_mean + amp_g * np.exp(-0.5 * ((elev - centre) / sigma) ** 2), elev,
                    color="tab:olive", lw=0.7)
    ax.set_xlim(lo - 0.05 * (hi - lo), hi + 0.35 * (hi - lo))
    if np.isfinite(mk.top) and np.isfinite(mk.bottom):   # the signal, with some noise
        span = max(mk.top - mk.bottom, 5.0)
        ax.set_ylim(mk.bottom - 0.6 * span, mk.top + 0.6 * span)
    ax.set_xlabel("received energy (counts)")
    ax.set_ylabel(f"elevation (m, {vertical_datum})")
    ax.ticklabel_format(useOffset=False, style="plain", axis="y")
    ax.set_title(title or f"{d.beam} shot {d.shot_number} ({d.setting}, {d.flag})",
                 fontsize=9)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7,
              borderaxespad=0.0)  # outside the waveform
    return save_figure(fig, path)


def waveform_html(details_list: Sequence[ShotDetails], path: str | os.PathLike[str], *,
                  title: str = "canopyblocks: waveforms") -> Path:
    """One self-contained HTML page: each shot's plot (embedded PNG) and its numbers."""
    import tempfile

    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             "</title><style>body{font-family:sans-serif;margin:1em}figure{display:inline-"
             "block;margin:0.5em;vertical-align:top}td,th{padding:2px 6px;text-align:right}"
             "</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    with tempfile.TemporaryDirectory() as tmp:
        for d in details_list:
            png = plot_waveform(d, Path(tmp) / f"{d.shot_number}.png")
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            rows = "".join(f"<tr><th>RH{k}</th><td>{v:.2f} m</td></tr>"
                           for k, v in sorted(d.rh.items()) if k in RH_MARKED)
            parts.append(
                f"<figure><img src='data:image/png;base64,{data}' width='420'>"
                f"<figcaption><table><tr><th>beam</th><td>{html.escape(d.beam)}</td></tr>"
                f"<tr><th>shot</th><td>{d.shot_number}</td></tr>"
                f"<tr><th>flag</th><td>{html.escape(d.flag)}</td></tr>"
                f"<tr><th>ground</th><td>{d.ground:.2f} m</td></tr>"
                f"<tr><th>top</th><td>{d.top:.2f} m</td></tr>{rows}</table></figcaption>"
                "</figure>")
    parts.append("</body></html>")
    p = Path(path)
    with atomic_output(p) as t:
        Path(t).write_text("\n".join(parts), encoding="utf-8")
    return p


def plots_index(pngs: Sequence[str | os.PathLike[str]], path: str | os.PathLike[str]) -> Path:
    """An HTML page showing waveform PNGs that sit in its folder (relative links)."""
    body = "".join(f"<figure><img src='{html.escape(Path(p).name)}' width='380'>"
                   f"<figcaption>{html.escape(Path(p).stem)}</figcaption></figure>"
                   for p in pngs)
    out = Path(path)
    with atomic_output(out) as tmp:
        Path(tmp).write_text("<!doctype html><meta charset='utf-8'><title>waveforms</title>"
                             "<style>figure{display:inline-block}</style>" + body,
                             encoding="utf-8")
    return out
