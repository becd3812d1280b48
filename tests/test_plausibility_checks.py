"""Regression tests of issue 10's silent-wrong-number classes fixed in the core.

Each builds its input with a known answer (synthetic photons, the bundled tiles whose
nature is documented in tests/data/PROVENANCE.md) and checks the flag, warning or refusal.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from canopyblocks import BlockParams, PhotonTrack, compute_blocks, read_las
from canopyblocks.blocks.plausibility import MAX_CANOPY_HEIGHT_M, ImplausibleBlockWarning
from canopyblocks.errors import InputError
from canopyblocks.readers.cloud_checks import NormalisedCloudWarning, looks_normalised

CRS = "EPSG:32613"


def _track(s: np.ndarray, h: np.ndarray, conf: np.ndarray | None = None) -> PhotonTrack:
    n = s.size
    return PhotonTrack(time=np.arange(n, dtype=float), lat=np.zeros(n), lon=np.zeros(n), h=h,
                       x=500000.0 + s, y=np.full(n, 4.0e6), s=s, track="gt1r", crs=CRS,
                       signal_conf=conf)


def test_fill_value_in_s_is_refused_not_an_overflowed_block() -> None:
    """Item 4: one s = 3.4028235e38 made block -9223372036854775808 flagged 'ok'."""
    rng = np.random.default_rng(1)
    s = np.sort(rng.uniform(0, 100, 400))
    s[-1] = 3.4028235e38
    with pytest.raises(InputError, match="fill values"):
        compute_blocks(_track(s, rng.uniform(0, 20, 400)), BlockParams(lengths=(25.0,)))


def test_blocks_taller_than_any_tree_are_flagged_with_the_noise_share() -> None:
    """Item 7: background photons spread over 300 m give a 'canopy' no tree has."""
    rng = np.random.default_rng(2)
    n = 4000
    s = np.sort(rng.uniform(0, 100, n))
    noise = rng.random(n) < 0.8  # 80 % background, uniform over 300 m
    h = np.where(noise, rng.uniform(-50, 250, n), rng.normal(0.0, 0.2, n))
    conf = np.where(noise, 0, 4).astype(np.int8)
    share = f"{noise.mean():.0%}"  # the background share, counted here
    with pytest.warns(ImplausibleBlockWarning, match=f"{share} of its photons are background"):
        blocks = compute_blocks(_track(s, h, conf), BlockParams(lengths=(25.0,)))
    tall = blocks["hmax"] > MAX_CANOPY_HEIGHT_M
    assert tall.any(), "the test needs blocks above the limit"
    assert (blocks.loc[tall, "flag"] == "implausible").all()
    assert not (blocks.loc[~tall, "flag"] == "implausible").any()
    # with the land-confidence filter the same photons give ground at 0 and no flag
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImplausibleBlockWarning)
        clean = compute_blocks(_track(s, h, conf), BlockParams(lengths=(25.0,),
                                                                min_signal_conf=2))
    assert (clean["flag"] != "implausible").all()
    assert np.abs(clean["ground"]).max() < 1.0


def test_height_normalised_tile_is_warned_about(sample) -> None:
    """Item 3: lidR_MixedConifer.laz is height-normalised (ground at z = 0)."""
    with pytest.warns(NormalisedCloudWarning, match="height-normalised"):
        read_las(sample("als/lidR_MixedConifer.laz"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", NormalisedCloudWarning)
        pts = read_las(sample("als/lidR_Topography.laz"))  # real elevations
    assert float(np.median(pts.z[pts.classification == 2])) > 100.0


def test_looks_normalised_on_known_ground_heights() -> None:
    rng = np.random.default_rng(3)
    assert looks_normalised(rng.normal(0.0, 0.05, 500))[0]
    assert not looks_normalised(rng.normal(812.0, 3.0, 500))[0]  # a real terrain
    assert not looks_normalised(rng.normal(0.0, 5.0, 500))[0]  # coastal terrain, varied
