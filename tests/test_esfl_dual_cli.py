"""``canopyblocks simulate --sensor dual --dual-noise``: the paper's 5 % by default."""

from __future__ import annotations

import subprocess
import sys

import h5py


def _cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def test_dual_noise_default_and_option(sample, tmp_path):
    las = sample("als/lidR_MixedConifer.laz")
    for extra, want in (((), 0.05), (("--dual-noise", "0"), 0.0)):
        out = tmp_path / f"dual{want}.h5"
        r = _cli("simulate", las, "--sensor", "dual", "--azimuth", "0", "-o", out, *extra)
        assert r.returncode == 0, r.stderr
        with h5py.File(out) as f:
            assert f.attrs["noise"] == want
            assert f["visible"].shape[0] >= 3
    r = _cli("simulate", las, "--sensor", "gedi", "--azimuth", "0", "--dual-noise", "0.1",
             "-o", tmp_path / "g.h5")
    assert r.returncode == 2 and "--dual-noise" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "g.h5").exists()
