"""GEDI L1B geometry, sample pool and amplitude checks (issue 23 item 1, item 6 and the
waveform tracebacks): damaged copies of the real subset, judged against the official L2A
of the same shots (read here with plain h5py), hand-made arrays with known answers, and
the command line's summary and exit status."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from badinputs.gedi_corpus import assert_no_contradiction  # noqa: E402
from badinputs.gedi_damage import (  # noqa: E402
    BEAM,
    DAMAGES,
    GediDamage,
    check_footprints,
    damaged,
    damaged_shot_numbers,
    l2a_truth,
)
from canopyblocks.errors import CanopyBlocksError, NoUsableDataError  # noqa: E402
from canopyblocks.readers.gedi_geometry import (  # noqa: E402
    AMPLITUDE,
    POOL,
    POSITION,
    SAMPLE_SPACING_M,
    SPACING,
    amplitude_problems,
    geometry_problems,
)
from canopyblocks.workflows.waveforms import compare_with_l2a, footprints_from_l1b  # noqa: E402


@pytest.fixture(scope="module")
def truth(gedi_l2a: Path) -> dict[int, tuple[float, ...]]:
    return l2a_truth(gedi_l2a)


def test_no_real_shot_is_flagged(gedi_l1b: Path, truth) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        table, _ = footprints_from_l1b(gedi_l1b)
    assert len(table) == 300 and (table["flag"] == "ok").all()
    check_footprints(table, truth, set())


@pytest.mark.parametrize("damage", DAMAGES, ids=[d.name for d in DAMAGES])
def test_damaged_l1b(damage: GediDamage, gedi_l1b: Path, truth, tmp_path: Path) -> None:
    path = damaged(gedi_l1b, tmp_path / f"{damage.name}.h5", damage.edit)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            table, _ = footprints_from_l1b(path, beams=damage.beams)
        except CanopyBlocksError as exc:
            msg = str(exc)
            assert damage.refuse, f"refused an input with sound shots: {msg}"
            assert path.name in msg and "\n" not in msg
            assert any(n.lower() in msg.lower() for n in damage.needles), msg
            return
    assert not damage.refuse, f"accepted ({dict(table['flag'].value_counts())})"
    check_footprints(table, truth, damaged_shot_numbers(gedi_l1b, damage.shots))
    said = " ".join(str(w.message) for w in caught)
    assert_no_contradiction([str(w.message) for w in caught])
    assert not damage.warn_words or any(w in said for w in damage.warn_words), \
        f"no warning naming it: {said}"


def test_geometry_problems_on_hand_made_shots() -> None:
    s = SAMPLE_SPACING_M
    count = np.array([11, 11, 11, 11, 11, 0, 11, 11])
    start = np.array([1, 12, 23, 34, 40, 60, 51, 62])      # shot 4 overlaps shot 3
    e0 = np.array([110.0, 110.0, 100.0, 110.0, 110.0, np.nan, 110.0, 110.0])
    e1 = e0 - 10 * s
    e1[1] = 110.0 + 10 * s                                  # upside down
    e1[2] = e0[2] - 10 * s * 1.002                          # 0.2 % long: one sample short
    lat = np.array([10.0, 10, 10, 10, 10, 10, 91.0, 10])   # shot 6 beyond the pole
    lon = np.full(8, 20.0)
    p = geometry_problems(count, start, e0, e1, lat, lat, lon, lon)
    assert p.tolist() == [0, SPACING, SPACING, POOL, POOL, 0, POSITION, 0]
    # off nadir: 0.5 % short is sound
    ok = geometry_problems([11], [1], [100.0], [100.0 - 10 * s * 0.995], [0.0], [0.0],
                           [0.0], [0.0])
    assert ok.tolist() == [0]


def test_overlap_blames_the_shot_whose_count_misfits() -> None:
    s = SAMPLE_SPACING_M
    # shot 0 claims 30 samples over a 10-sample span and runs into shot 1
    p = geometry_problems([30, 11], [1, 12], [110.0, 110.0], [110.0 - 10 * s] * 2,
                          [0.0] * 2, [0.0] * 2, [0.0] * 2, [0.0] * 2)
    assert p.tolist() == [SPACING | POOL, 0]


def test_amplitude_problems_ignore_padding() -> None:
    w = np.array([[200.0, 900.0, 5e5], [200.0, 2e4, 200.0]], dtype=np.float32)
    assert amplitude_problems(w, [2, 3]).tolist() == [0, AMPLITUDE]


def _cli(args: list[str]) -> tuple[int, str]:
    import contextlib
    import io

    from canopyblocks.cli import cli
    from canopyblocks.cli.common import run_main

    err = io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stderr(err), \
            contextlib.redirect_stdout(io.StringIO()):
        code = run_main(cli, args)
    return code, err.getvalue()


def test_summary_counts_flagged_shots(gedi_l1b: Path, tmp_path: Path) -> None:
    bad = next(d for d in DAMAGES if d.name == "bin0-nan")
    path = damaged(gedi_l1b, tmp_path / "nan.h5", bad.edit)
    code, err = _cli(["waveforms", str(path), "-o", str(tmp_path / "f.csv")])
    assert code == 0, err
    last = err.strip().splitlines()[-1]
    assert "ok 299" in last and "invalid_shot 1" in last and "ok 300" not in last, last
    assert "canopyblocks: warning:" in err and "invalid_shot" in err


@pytest.mark.parametrize("name", ["count-strings", "rxwaveform-2d"])
def test_bad_dataset_types_exit_2_naming_file_and_dataset(name, gedi_l1b, tmp_path) -> None:
    d = next(x for x in DAMAGES if x.name == name)
    path = damaged(gedi_l1b, tmp_path / f"{name}.h5", d.edit)
    out = tmp_path / "f.gpkg"
    code, err = _cli(["waveforms", str(path), "-o", str(out)])
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert path.name in lines[0] and d.needles[0] in lines[0], lines[0]
    assert not out.exists()


@pytest.mark.parametrize("name", ["count-strings", "rxwaveform-2d"])
def test_a_worker_refusing_a_beam_ends_the_command(name, gedi_l1b, tmp_path) -> None:
    """``waveforms --workers 2`` (the default on two cores): one worker refuses a damaged
    beam while the other reads another; the command ends at once with the one-line
    refusal. (It hung for ever: the idle worker swallowed the pool's SIGTERM inside a
    weakref callback, printed 'Exception ignored ... SystemExit: 143', and was waited for.)"""
    import subprocess
    import time

    d = next(x for x in DAMAGES if x.name == name)
    path = damaged(gedi_l1b, tmp_path / f"{name}.h5", d.edit)
    out = tmp_path / "f.gpkg"
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "waveforms", str(path),
                        "--workers", "2", "-o", str(out)], capture_output=True, text=True,
                       timeout=120)
    took = time.monotonic() - t0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "XDG_RUNTIME" not in ln]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "Exception ignored" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert path.name in lines[0] and d.needles[0] in lines[0], lines[0]
    assert took < 60, f"{took:.0f} s to refuse"
    assert not out.exists()


def _other_shots(src: Path, dst: Path) -> Path:
    def edit(f: h5py.File) -> None:
        for b in [k for k in f if k.startswith("BEAM")]:
            f[f"{b}/shot_number"][()] = f[f"{b}/shot_number"][()] + np.uint64(10**12)
    return damaged(src, dst, edit)


def test_l2a_of_other_shots_is_refused(gedi_l1b: Path, gedi_l2a: Path, tmp_path) -> None:
    other = _other_shots(gedi_l2a, tmp_path / "other_l2a.h5")
    out = tmp_path / "f.gpkg"
    code, err = _cli(["waveforms", str(gedi_l1b), "--beam", BEAM, "--l2a", str(other),
                      "-o", str(out)])
    assert code == 2 and "other_l2a.h5" in err and "none of the 73" in err, err
    assert "nan" not in err and not out.exists()


def _l2b(path: Path, l1b: Path, shift: int = 0) -> Path:
    """An L2B-layout file with the L1B's BEAM0101 shots and known cover 0.25."""
    with h5py.File(l1b) as src:
        sn = src[f"{BEAM}/shot_number"][()] + np.uint64(shift)
        lat = src[f"{BEAM}/geolocation/latitude_bin0"][()]
        lon = src[f"{BEAM}/geolocation/longitude_bin0"][()]
    with h5py.File(path, "w") as f:
        g = f.create_group(BEAM)
        g["shot_number"] = sn
        g["cover"] = np.full(sn.size, 0.25, np.float32)
        g["geolocation/lat_lowestmode"] = lat
        g["geolocation/lon_lowestmode"] = lon
    return path


def test_l2b_comparison_is_labelled_l2b(gedi_l1b: Path, tmp_path: Path) -> None:
    l2b = _l2b(tmp_path / "l2b.h5", gedi_l1b)
    code, err = _cli(["waveforms", str(gedi_l1b), "--beam", BEAM, "--l2b", str(l2b),
                      "-o", str(tmp_path / "f.csv")])
    assert code == 0, err
    assert "vs L2B cover" in err and "vs L2A cover" not in err and "n=73" in err, err
    with pytest.raises(NoUsableDataError, match="none of the 73"):
        table, _ = footprints_from_l1b(gedi_l1b, beams=BEAM)
        compare_with_l2a(table, l2b=_l2b(tmp_path / "o.h5", gedi_l1b, shift=10**12))


def test_partly_matching_l2a_warns(gedi_l1b: Path, gedi_l2a: Path) -> None:
    table, _ = footprints_from_l1b(gedi_l1b, beams=[BEAM, "BEAM0001"])
    sub = table[table["beam"] == BEAM]
    joined, stats = compare_with_l2a(sub, gedi_l2a)      # every shot matches: no warning
    assert stats.loc[stats["metric"] == "ground", "n"].iloc[0] == 73
    table.loc[0, "shot_number"] = 12345
    with pytest.warns(UserWarning, match="1 of 89 footprints have no shot"):
        compare_with_l2a(table, gedi_l2a)
