"""Corpus cases of damaged GEDI L1B files (:mod:`badinputs.gedi_damage`), through the API
(``footprints_from_l1b``, judged against the official L2A of the same shots) and a sample
through the command line (``waveforms``: exit 2 with one line, or exit 0 with the warning).

Registered in :func:`badinputs.make_corpus.all_cases`; the runner ``gedi`` is added to the
corpus test's runners through :data:`RUNNERS`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from .gedi_damage import (
    DAMAGES,
    GediDamage,
    check_footprints,
    damaged,
    damaged_shot_numbers,
    l2a_truth,
    unzipped,
)

__all__ = ["gedi_cases", "RUNNERS", "CLI_SAMPLE"]

#: damages also fed to ``canopyblocks waveforms`` (in-process)
CLI_SAMPLE = ("bin0-lastbin-swapped", "starts-swapped", "sample-1e6", "lat-200", "bin0-fill",
              "all-swapped", "rx-scaled-1000", "count-strings", "rxwaveform-2d",
              "beam-without-rxwaveform")


def _make(d: GediDamage) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        l1b, l2a = unzipped(base.data_file, base.folder / "gedi")
        path = damaged(l1b, folder / f"gedi_{d.name}.h5", d.edit)
        return {"path": path, "l2a": l2a, "beams": d.beams,
                "bad": damaged_shot_numbers(l1b, d.shots)}
    return make


def _make_cli(d: GediDamage) -> Callable[[Path, Any], dict[str, Any]]:
    inner = _make(d)

    def make(folder: Path, base: Any) -> dict[str, Any]:
        i = inner(folder, base)
        out = folder / "out" / "footprints.gpkg"
        # two workers (the default on two cores): a refusal inside a worker ends the
        # command (it hung when an idle worker swallowed the pool's SIGTERM)
        i["args"] = ["waveforms", str(i["path"]), "--workers", "2", "-o", str(out)] + \
            [a for b in (d.beams or ()) for a in ("--beam", b)]
        i["outputs"] = [out]
        return i
    return make


def run_gedi(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks.workflows.waveforms import footprints_from_l1b

    return footprints_from_l1b(i["path"], beams=i["beams"])[0]


def check_gedi(case: Any, i: dict[str, Any], table: Any, ws: list[str]) -> None:
    check_footprints(table, l2a_truth(i["l2a"]), i["bad"])
    assert_no_contradiction(ws)
    if case.warn_words:
        said = " ".join(ws).lower()
        assert any(w.lower() in said for w in case.warn_words), \
            f"no warning about {case.warn_words}: {ws}"


def assert_no_contradiction(ws: list[str]) -> None:
    """A shot flagged ``invalid_shot`` (heights not given) is not also reported as having
    wrong heights by a later step: one cause, told once."""
    said = " ".join(ws)
    if "invalid_shot" in said:
        assert "heights are wrong" not in said, f"contradictory warnings: {ws}"


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
    "gedi": (run_gedi, check_gedi)}


def _other_shots(src: Path, dst: Path) -> Path:
    """An L2A (or L2B-shaped) copy whose shot numbers are other shots'."""
    import h5py
    import numpy as np

    def edit(f: h5py.File) -> None:
        for b in [k for k in f if k.startswith("BEAM")]:
            f[f"{b}/shot_number"][()] = f[f"{b}/shot_number"][()] + np.uint64(10**12)
    return damaged(src, dst, edit)


def _l2_cli(option: str) -> Callable[[Path, Any], dict[str, Any]]:
    """``waveforms L1B --l2a/--l2b OTHER``: a comparison with no shot in common."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        l1b, l2a = unzipped(base.data_file, base.folder / "gedi")
        other = _other_shots(l2a, folder / "other_l2a.h5")
        out = folder / "out" / "footprints.gpkg"
        return {"path": other, "args": ["waveforms", str(l1b), "--beam", "BEAM0101", option,
                                         str(other), "-o", str(out)], "outputs": [out]}
    return make


def _truncated_cli(keep: float) -> Callable[[Path, Any], dict[str, Any]]:
    """``waveforms`` on a copy of the L1B cut short (``keep``: the fraction kept)."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        l1b, _ = unzipped(base.data_file, base.folder / "gedi")
        raw = l1b.read_bytes()
        path = folder / f"GEDI01_B_cut_{keep:g}.h5"
        path.write_bytes(raw[:max(1, int(len(raw) * keep))])
        out = folder / "out" / "footprints.gpkg"
        return {"path": path, "args": ["waveforms", str(path), "-o", str(out)],
                "outputs": [out]}
    return make


def _zeroed_cli(start: float, stop: float) -> Callable[[Path, Any], dict[str, Any]]:
    """``waveforms`` on a copy of the L1B of full size with bytes ``start``..``stop`` (the
    fractions of its size) zeroed, as a preallocated download that stopped."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        l1b, _ = unzipped(base.data_file, base.folder / "gedi")
        raw = bytearray(l1b.read_bytes())
        a, b = int(len(raw) * start), int(len(raw) * stop)
        raw[a:b] = bytes(b - a)
        path = folder / f"GEDI01_B_zeroed_{start:g}_{stop:g}.h5"
        path.write_bytes(bytes(raw))
        out = folder / "out" / "footprints.gpkg"
        return {"path": path, "args": ["waveforms", str(path), "-o", str(out)],
                "outputs": [out]}
    return make


_SERVERS: dict[str, Any] = {}


def _short_server(root: Path) -> str:
    """The URL of a loopback HTTP server of ``root`` (tests/loopback_servers.py), started
    once for the session (stopped at exit)."""
    import atexit

    from loopback_servers import RangeHTTPServer

    if str(root) not in _SERVERS:
        server = RangeHTTPServer(root).__enter__()
        atexit.register(server.__exit__, None, None, None)
        _SERVERS[str(root)] = server
    return str(_SERVERS[str(root)].url)


def _short_answers_cli(mode: str) -> Callable[[Path, Any], dict[str, Any]]:
    """``waveforms`` on the L1B over http from a server whose range answers are short
    (``short``: half of every one; ``capped``: at most 40,000 bytes, as behind a proxy)."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        l1b, _ = unzipped(base.data_file, base.folder / "gedi")
        served = folder / "served" / mode
        served.mkdir(parents=True)
        (served / l1b.name).write_bytes(l1b.read_bytes())
        url = f"{_short_server(folder / 'served')}/{mode}/{l1b.name}"
        out = folder / "out" / "footprints.gpkg"
        return {"path": None, "name": url, "args": ["waveforms", url, "-o", str(out)],
                "outputs": [out]}
    return make


def _gedi_option(sensor: str, spacing: str) -> Callable[[Path, Any], dict[str, Any]]:
    """``simulate --sensor S --shot-spacing X``: honoured for gedi, refused for others."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        out = folder / "out" / "sim.h5"
        return {"path": None, "name": "--shot-spacing",
                "args": ["simulate", str(base.conifer), "--sensor", sensor, "--azimuth", "0",
                         "--shot-spacing", spacing, "-o", str(out)], "outputs": [out]}
    return make


def gedi_cases() -> list[Any]:
    from .make_corpus import Case

    cases = [Case(f"gedi-{d.name}", "gedi", _make(d), needles=d.needles,
                  warn_words=d.warn_words, must_refuse=d.refuse) for d in DAMAGES]
    baseline = GediDamage("baseline", lambda f: None, warn_words=(), beams=None)
    cases.append(Case("baseline-gedi", "gedi", _make(baseline), must_accept=True))
    for d in DAMAGES:
        if d.name in CLI_SAMPLE:
            cases.append(Case(f"cli-waveforms-gedi-{d.name}", "cli", _make_cli(d),
                              needles=d.needles, warn_words=d.warn_words,
                              must_refuse=d.refuse))
    cases.append(Case("cli-waveforms-gedi-l2a-of-other-shots", "cli", _l2_cli("--l2a"),
                      needles=("none of the",), must_refuse=True))
    cases.append(Case("cli-waveforms-gedi-l2a-file-as-l2b", "cli", _l2_cli("--l2b"),
                      needles=("l2b",), must_refuse=True))
    for keep in (0.000001, 0.001, 0.5, 0.9999):  # cut short: never "not a GEDI file"
        cases.append(Case(f"cli-waveforms-gedi-truncated-{keep:g}", "cli", _truncated_cli(keep),
                          needles=("download it again",), forbidden=("not a gedi",),
                          must_refuse=True))
    for start, stop in ((0.6, 1.0), (0.475, 0.525)):  # zeroed: damaged, not "not GEDI"
        cases.append(Case(f"cli-waveforms-gedi-zeroed-{start:g}-{stop:g}", "cli",
                          _zeroed_cli(start, stop), needles=("the file is damaged",),
                          forbidden=("not a gedi", "subset"), must_refuse=True))
    for mode in ("short", "capped"):  # the server's answers short: named, not the file
        cases.append(Case(f"cli-waveforms-gedi-over-http-{mode}-answers", "cli",
                          _short_answers_cli(mode), needles=("answers were short",),
                          forbidden=("not a gedi",), must_refuse=True))
    for sensor, spacing, needle in (("gedi", "0.00001", "spacing"),
                                    ("esfl", "10", "shot-spacing"),
                                    ("dual", "10", "shot-spacing")):
        cases.append(Case(f"cli-simulate-{sensor}-shot-spacing={spacing}", "cli",
                          _gedi_option(sensor, spacing), needles=(needle,),
                          must_refuse=True))
    return cases
