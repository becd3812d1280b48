"""Corpus cases for co-registration: tracks with no offset, rasters that miss the track.

The photons are the corpus' simulated track over the Topography tile (exactly geolocated:
the true offset is zero) and the rasters the corpus makes there with numpy. Right
answers:

* no offset (photons, 25 m blocks, ``validate --coregister``): exit 0 with a warning that
  the offset is undetermined (nothing applied), never an offset reported ``ok``;
* rasters moved off the track (50 km away, or overlapping a sliver at its edge): refused,
  one line naming the DTM and how much of the track it covers, never "widen the range"
  or an offset at the edge of the search grid.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .base import Base

Inputs = dict[str, Any]


def _moved_rasters(base: Base, folder: Path, dx: float, tag: str) -> dict[str, Path]:
    """Copies of the corpus rasters with their origin moved ``dx`` m east."""
    import rasterio
    from rasterio.transform import Affine

    out = {}
    for name, src in base.rasters["paths"].items():
        dst = folder / f"{name}_{tag}.tif"
        with rasterio.open(src) as r:
            profile = dict(r.profile)
            data = r.read(1)
        t = profile["transform"]
        profile["transform"] = Affine(t.a, t.b, t.c + dx, t.d, t.e, t.f)
        with rasterio.open(dst, "w", **profile) as w:
            w.write(data, 1)
        out[name] = dst
    return out


def _photons(base: Base) -> Path:
    base.blocks  # noqa: B018 - makes the simulated photons too
    return base.folder / "blocks" / "sim_atl03.h5"


def _coregister_args(source: Path, rasters: dict[str, Path], out: Path) -> list[str]:
    return ["coregister", str(source), "--dtm", str(rasters["dtm"]), "--dsm-max",
            str(rasters["dsm_max"]), "--offset", "0", "-o", str(out)]


def _validate_args(rasters: dict[str, Path], blocks: Path, out: Path) -> list[str]:
    return ["validate", str(blocks), "--dtm", str(rasters["dtm"]), "--dsm-max",
            str(rasters["dsm_max"]), "--dsm-p90", str(rasters["dsm_p90"]), "--offset", "0",
            "--width", "13", "--coregister", "-o", str(out)]


def coregistration_cases() -> list[Any]:
    """The cases (``make_corpus.Case``), command line, in-process."""
    from .make_corpus import Case

    def zero(kind: str) -> Any:
        def make(folder: Path, base: Base) -> Inputs:
            rasters = dict(base.rasters["paths"])
            if kind == "validate":
                out = folder / "out" / "validation.gpkg"
                args = _validate_args(rasters, base.blocks, out)
                extra = {"ranges": base.rasters["ranges"]}
            else:
                out = folder / "out" / "offsets.json"
                source = _photons(base) if kind == "photons" else base.blocks
                args = _coregister_args(source, rasters, out)
                extra = {}
            (folder / "out").mkdir(exist_ok=True)
            return {"path": None, "args": args, "outputs": [out], **extra}
        return make

    def missed(kind: str, dx: float | None, tag: str) -> Any:
        def make(folder: Path, base: Base) -> Inputs:
            if dx is None:  # a 12 m sliver of the rasters left under the tile's east edge
                prof = base.rasters["profile"]
                shift = prof["width"] * prof["transform"].a - 12.0
            else:
                shift = dx
            rasters = _moved_rasters(base, folder, shift, tag)
            (folder / "out").mkdir(exist_ok=True)
            if kind == "validate":
                out = folder / "out" / "validation.gpkg"
                args = _validate_args(rasters, base.blocks, out)
            else:
                out = folder / "out" / "offsets.json"
                args = _coregister_args(_photons(base), rasters, out)
            return {"path": None, "name": rasters["dtm"].name, "args": args, "outputs": [out]}
        return make

    cases = [Case(f"cli-coregister-zero-offset-{kind}", "cli", zero(kind),
                  warn_words=("undetermined",))
             for kind in ("photons", "blocks", "validate")]
    for kind in ("photons", "validate"):
        for tag, dx in (("elsewhere", 50_000.0), ("sliver", None)):
            cases.append(Case(f"cli-coregister-rasters-{tag}-{kind}", "cli",
                              missed(kind, dx, tag), needles=("cover",),
                              forbidden=("widen", "search range"), must_refuse=True))
    return cases

