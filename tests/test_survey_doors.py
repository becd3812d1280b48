"""Every door takes the same survey: `run`, `validate --points`, `batch --tiles` given the
survey as its LAZ tiles, a folder, a .vpc catalog, a COPC over https:// and an EPT dataset
over s3:// (real servers on the loopback address) give the same residuals; `batch` and
`run` give the same blocks, counts and residuals; a survey in Web Mercator (EPSG:3857)
gives the residuals of the same survey in UTM within 0.05 m.

Independent truths: the run on the local LAZ tiles (each source kind is checked against it,
not against itself), and the survey reprojected here point by point with pyproj (the UTM
and Web Mercator copies are both made from the same BC Albers tiles).
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from canopyblocks.readers import remote
from copc_data import build_octree, tile_points, write_copc, write_ept
from loopback_servers import RangeHTTPServer, S3Server, use_s3_server
from test_survey_sources import write_vpc

gpd = pytest.importorskip("geopandas")
pytestmark = [pytest.mark.slow,
              pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")]

TILES = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
KINDS = ("folder", "vpc", "https_copc", "s3_ept")
COLUMNS = ("res_ground", "res_hmax", "ref_ground", "ref_top")


@pytest.fixture(scope="module")
def survey(tmp_path_factory, sample):  # noqa: ANN001
    """The survey in every form, a simulated granule over it, the servers (module-wide)."""
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    root = tmp_path_factory.mktemp("doors")
    tiles = [sample(t) for t in TILES]
    (root / "tiles").mkdir()
    for t in tiles:
        shutil.copy(t, root / "tiles" / t.name)
    tree = build_octree(tile_points(tiles), capacity=5000)
    write_copc(tiles, root / "survey.copc.laz", tree=tree, page_level=2)
    write_ept(tiles, root / "ept", tree=tree, split_level=2)
    write_vpc(root / "survey.vpc", [f"./tiles/{t.name}" for t in tiles])
    pts = read_las(tiles)
    b = pts.bounds
    track = line_through(b, 10.0, centre=((b[0] + b[2]) / 2 + 30, (b[1] + b[3]) / 2),
                         inset=7, name="gt1r")
    sim = simulate_photons(pts, track, SimParams(), realisations=1, seed=21)
    granule = root / "ATL03_sim.h5"
    write_simulation_atl03(sim, granule, realisations=(0,))
    with RangeHTTPServer(root) as http, S3Server() as s3, pytest.MonkeyPatch.context() as mp:
        for f in sorted((root / "ept").rglob("*")):
            if f.is_file():
                s3.put("surveys", f"bc/ept/{f.relative_to(root / 'ept')}", f)
        use_s3_server(mp, s3.endpoint, root)
        remote.clear_cache()
        yield {"root": root, "granule": granule,
               "laz": [str(root / "tiles" / t.name) for t in tiles],
               "folder": [str(root / "tiles")], "vpc": [str(root / "survey.vpc")],
               "https_copc": [f"{http.url}/survey.copc.laz"],
               "s3_ept": ["s3://surveys/bc/ept/ept.json"]}


def _run(survey: dict, kind: str) -> Path:
    from canopyblocks.blocks import BlockParams
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.workflows.chain.run import run_chain

    out = survey["root"] / f"run_{kind}"
    if not (out / "validation.gpkg").exists():
        run_chain(survey[kind], out, photons=str(survey["granule"]), beams=["gt1r"],
                  params=BlockParams(lengths=(25.0,)), estimators=preset("paper"),
                  width=13.0, offset=0.0, compare_preset=None)
    return out


def _layer(folder: Path, layer: str) -> pd.DataFrame:
    r = gpd.read_file(folder / "validation.gpkg", layer=layer)
    return r.sort_values(["track", "length", "block"]).reset_index(drop=True)


def _same(a: pd.DataFrame, b: pd.DataFrame, what: str, atol: float = 1e-6) -> None:
    assert len(a) == len(b) > 10, what
    np.testing.assert_array_equal(a["block"].to_numpy(), b["block"].to_numpy(), err_msg=what)
    np.testing.assert_array_equal(a["use"].to_numpy(), b["use"].to_numpy(), err_msg=what)
    for c in COLUMNS:
        np.testing.assert_allclose(a[c].to_numpy(float), b[c].to_numpy(float), atol=atol,
                                   equal_nan=True, err_msg=f"{what}: {c}")


@pytest.mark.parametrize("kind", KINDS)
def test_run_takes_every_form_of_the_survey(survey, kind: str) -> None:  # noqa: ANN001
    want = _run(survey, "laz")
    got = _run(survey, kind)
    for layer in ("residuals", "residuals_footprint"):
        _same(_layer(got, layer), _layer(want, layer), f"{kind} {layer}")


@pytest.mark.parametrize("kind", KINDS)
def test_validate_points_takes_every_form_of_the_survey(survey, kind: str) -> None:  # noqa: ANN001
    from canopyblocks.workflows.validate import validate_file

    blocks = _run(survey, "laz") / "blocks.gpkg"
    outs = {}
    for k in ("laz", kind):
        outs[k] = survey["root"] / f"validate_{k}.gpkg"
        if not outs[k].exists():
            validate_file(blocks, outs[k], points=survey[k], reference="footprint",
                          offset=0.0)
    a = gpd.read_file(outs[kind], layer="residuals").sort_values(["track", "length", "block"])
    b = gpd.read_file(outs["laz"], layer="residuals").sort_values(["track", "length", "block"])
    _same(a.reset_index(drop=True), b.reset_index(drop=True), kind)


def _batch(survey: dict, kind: str) -> pd.DataFrame:
    from canopyblocks.outputs.tables import read_layer
    from canopyblocks.workflows.batch import BatchConfig, run_batch

    out = survey["root"] / f"batch_{kind}"
    if not (out / "residuals.parquet").exists():
        run_batch([str(survey["granule"])], survey[kind], out,
                  BatchConfig(lengths=(25.0,), width=13.0, offset=0.0, preset="paper"),
                  beams=["gt1r"])
    return pd.DataFrame(read_layer(out / "residuals.parquet"))


@pytest.mark.parametrize("kind", KINDS)
def test_batch_takes_every_form_of_the_survey(survey, kind: str) -> None:  # noqa: ANN001
    a, b = _batch(survey, kind), _batch(survey, "laz")
    _same(a.sort_values("block").reset_index(drop=True),
          b.sort_values("block").reset_index(drop=True), kind)


def test_batch_and_run_give_the_same_blocks(survey) -> None:  # noqa: ANN001
    """The blocks a run validates are the blocks the batch validates, with the same
    residuals: the batch reads the survey over the corridor as the run does, so a block
    over the seam between the two tiles is not "reference outside"."""
    run = _layer(_run(survey, "laz"), "residuals")
    batch = _batch(survey, "laz")
    a = run[run["use"]].reset_index(drop=True)
    b = batch[batch["use"]].sort_values("block").reset_index(drop=True)
    assert len(a) == len(b) > 10
    _same(a, b, "batch vs run")
    seam = 629400.0  # the two tiles meet here: blocks over it are validated
    near = (b["y"] - seam).abs() < 12.5
    assert near.any()


def _reprojected(src: Path, out: Path, epsg: int) -> Path:
    """``src`` with x/y reprojected to ``epsg`` (pyproj), heights as they are."""
    import laspy
    import pyproj

    las = laspy.read(src)
    crs_from = pyproj.CRS.from_wkt(las.header.parse_crs().to_wkt()) \
        if las.header.parse_crs() is not None else None
    assert crs_from is not None
    to = pyproj.Transformer.from_crs(crs_from, pyproj.CRS.from_epsg(epsg), always_xy=True)
    x, y = to.transform(np.asarray(las.x), np.asarray(las.y))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([np.floor(x.min()), np.floor(y.min()), 0.0])
    header.add_crs(pyproj.CRS.from_epsg(epsg))
    new = laspy.LasData(header)
    new.x, new.y, new.z = x, y, np.asarray(las.z)
    for name in ("classification", "return_number", "number_of_returns", "intensity"):
        setattr(new, name, np.asarray(getattr(las, name)))
    new.write(out)
    return out


def test_web_mercator_survey_gives_the_utm_residuals(survey, tmp_path: Path) -> None:  # noqa: ANN001
    from canopyblocks.blocks import BlockParams
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.workflows.chain.run import run_chain

    outs = {}
    for epsg in (32609, 3857):
        folder = tmp_path / f"tiles_{epsg}"
        folder.mkdir()
        for t in survey["laz"]:
            _reprojected(Path(t), folder / Path(t).name, epsg)
        outs[epsg] = tmp_path / f"run_{epsg}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_chain([str(folder)], outs[epsg], photons=str(survey["granule"]),
                      beams=["gt1r"], params=BlockParams(lengths=(25.0,)),
                      estimators=preset("paper"), width=13.0, offset=0.0,
                      compare_preset=None)
    for layer in ("residuals", "residuals_footprint"):
        a, b = _layer(outs[3857], layer), _layer(outs[32609], layer)
        assert a.crs.to_epsg() == b.crs.to_epsg() == 32609  # never metres of Web Mercator
        both = a["use"].to_numpy() & b["use"].to_numpy()
        assert both.sum() > 10
        for c in COLUMNS:
            diff = np.abs(a[c].to_numpy(float) - b[c].to_numpy(float))[both]
            print(f"3857 vs UTM {layer} {c}: max |diff| {np.nanmax(diff):.4f} m")
            assert np.nanmax(diff) <= 0.05, (layer, c)


@pytest.mark.parametrize("kind", ("vpc", "https_copc"))
def test_calibrate_points_takes_every_form_of_the_survey(survey, kind: str) -> None:  # noqa: ANN001
    from canopyblocks.blocks import BlockParams
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.workflows.calibrate import calibrate_bias_file

    fits = {k: calibrate_bias_file(str(survey["granule"]), BlockParams(lengths=(25.0,)),
                                   preset("paper"), points=survey[k], reference="footprint",
                                   offset=0.0, by_strength=False)
            for k in ("laz", kind)}
    got, want = fits[kind].models, fits["laz"].models
    assert len(got) == len(want) > 0
    for a, b in zip(got, want):  # the points in node order, not tile order: sums to 1e-9
        assert (a.metric, a.length, a.strength, a.n) == (b.metric, b.length, b.strength, b.n)
        for f in ("slope", "intercept", "rmse_after", "holdout_rmse_after"):
            assert getattr(a, f) == pytest.approx(getattr(b, f), abs=1e-6), f


def test_run_simulates_over_a_copc(survey) -> None:  # noqa: ANN001
    """`run` without photons over a COPC simulates in the COPC's own CRS (it used to pick a
    UTM zone the COPC's rasters then refused with "leave the CRS out")."""
    from canopyblocks.blocks import BlockParams
    from canopyblocks.workflows.chain.run import run_chain

    out = survey["root"] / "simulated_copc"
    run_chain([str(survey["root"] / "survey.copc.laz")], out, realisations=0, azimuth=10.0,
              params=BlockParams(lengths=(25.0,)), compare_preset=None)
    r = _layer(out, "residuals_footprint")
    assert r.crs.to_epsg() == 3005 and int(r["use"].sum()) > 5


def test_rasters_of_a_web_mercator_tile_are_made_in_utm(survey, tmp_path: Path) -> None:  # noqa: ANN001
    """`rasters` on an EPSG:3857 tile: 2 m cells on the ground (UTM), said in a warning,
    not 2 m of Web Mercator (1.27 m at 50.7 N)."""
    import pyproj
    import rasterio

    from canopyblocks.errors import CanopyBlocksWarning
    from canopyblocks.workflows.rasters import make_survey_rasters

    tile = _reprojected(Path(survey["laz"][0]), tmp_path / "merc.laz", 3857)
    with pytest.warns(CanopyBlocksWarning, match="not a metre on the ground"):
        made = make_survey_rasters([tile], tmp_path / "r", resolution=2.0, backend="serial")
    with rasterio.open(made.dsm_max) as src:
        assert pyproj.CRS(src.crs.to_wkt()).to_epsg() == 32609
        assert src.res == (2.0, 2.0)
        w, h = src.bounds.right - src.bounds.left, src.bounds.top - src.bounds.bottom
    assert 180 < w < 215 and 235 < h < 265  # the tile's 188 x 243 m, not 1.58 times that
