"""The shipped PDAL pipelines: valid JSON, portable stages, and each one runs as it is with
the ``pdal pipeline`` command line on a real tile (file names and bounds set by overriding
stage options); plus the runner and ``pdal info`` wrapper in canopyblocks.reference.pdal."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import CancelledError, FileFormatError, InputError, PdalError
from canopyblocks.progress import Progress
from canopyblocks.reference.pdal import (
    PIPELINES,
    expand_readers,
    insert_after_readers,
    load_pipeline,
    pipeline_path,
    run_pipeline,
    tile_info,
)

laspy = pytest.importorskip("laspy")
rasterio = pytest.importorskip("rasterio")

TILE = "als/pyfor_test.laz"  # EPSG:32617, classes 1, 2, 5, 7; x 405000-405200
BOX = (405100.0, 3276400.0, 405130.0, 3276430.0)
CROP = f"([{BOX[0]},{BOX[2]}],[{BOX[1]},{BOX[3]}])"
# stages PDAL 2.2 lacks or that changed meaning; the pipelines must run on 2.2 and current
FORBIDDEN = {"filters.expression", "readers.copc", "filters.projpipeline"}


@pytest.mark.parametrize("name", PIPELINES)
def test_pipeline_is_valid_portable_json(name: str) -> None:
    path = pipeline_path(name)
    doc = json.loads(path.read_text())
    stages = doc["pipeline"]
    assert stages[0]["type"] == "readers.las"
    assert sum(s["type"].startswith("readers.") for s in stages) == 1
    assert stages[-1]["type"].startswith("writers.")
    for s in stages:
        assert s["type"] not in FORBIDDEN
        assert "expression" not in s  # PDAL >= 2.3 only
    writer = stages[-1]
    if writer["type"] == "writers.gdal":
        assert writer["nodata"] == -9999
        assert writer["data_type"] == "float32"
        assert writer["window_size"] == 0
        assert math.isclose(writer["radius"], writer["resolution"] * math.sqrt(2) / 2)
        assert writer["output_type"] == ("mean" if name.startswith("dtm") else "max")


def test_pipeline_lookup() -> None:
    assert pipeline_path("dtm") == pipeline_path("dtm.json")
    assert pipeline_path("dtm").parent.name == "pdal_pipelines"
    with pytest.raises(InputError, match="dtm_idw"):
        pipeline_path("dtm_idw")


def test_expand_and_insert_are_data_edits() -> None:
    stages = load_pipeline("dsm_max")
    out = expand_readers(stages, [("a.laz", None), ("b.laz", "EPSG:32617")])
    assert [s["type"] for s in out[:3]] == ["readers.las", "readers.las", stages[1]["type"]]
    assert out[0]["filename"] == "a.laz" and "spatialreference" not in out[0]
    assert out[1]["spatialreference"] == "EPSG:32617"
    out2 = insert_after_readers(out, {"type": "filters.reprojection", "out_srs": "EPSG:1"})
    assert out2[2]["type"] == "filters.reprojection"
    assert stages == load_pipeline("dsm_max")  # the original is untouched


def _points(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    las = laspy.read(path)
    return (np.asarray(las.x), np.asarray(las.y), np.asarray(las.z),
            np.asarray(las.classification))


def _cli(pdal_bin: str, name: str, *opts: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([pdal_bin, "pipeline", str(pipeline_path(name)), *opts],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("name", ["dtm", "dsm_max", "dtm_smrf"])
def test_raster_pipelines_run_as_they_are(name: str, tmp_path: Path, pdal_bin: str,
                                          sample) -> None:  # noqa: ANN001
    out = tmp_path / f"{name}.tif"
    r = _cli(pdal_bin, name, f"--readers.las.filename={sample(TILE)}",
             f"--writers.gdal.filename={out}", f"--filters.crop.bounds={CROP}",
             f"--writers.gdal.origin_x={BOX[0]}", f"--writers.gdal.origin_y={BOX[1]}",
             "--writers.gdal.width=15", "--writers.gdal.height=15")
    assert r.returncode == 0, r.stderr
    with rasterio.open(out) as src:
        a = src.read(1)
        assert (src.width, src.height, src.dtypes[0], src.nodata) == (15, 15, "float32", -9999)
        assert tuple(src.transform)[:6] == (2.0, 0.0, BOX[0], 0.0, -2.0, BOX[3])
    x, y, z, c = _points(sample(TILE))
    inside = (x >= BOX[0]) & (x <= BOX[2]) & (y >= BOX[1]) & (y <= BOX[3])
    valid = a[a != -9999]
    assert valid.size > 100
    if name == "dsm_max":  # max of the non-noise points in the crop
        keep = inside & (c != 7) & (c != 18)
        assert valid.max() == pytest.approx(z[keep].max(), abs=1e-3)
    elif name == "dtm":  # cell means of ground points lie within the ground range
        g = inside & (c == 2)
        assert z[g].min() - 1e-3 <= valid.min() and valid.max() <= z[g].max() + 1e-3


def test_crop_corridor_runs_as_it_is(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    shapely = pytest.importorskip("shapely")
    # a 2 m wide corridor along a diagonal line, as a WKT polygon
    line = shapely.LineString([(405020.0, 3276320.0), (405180.0, 3276470.0)])
    poly = line.buffer(1.0, cap_style="flat")
    out = tmp_path / "corridor.laz"
    r = _cli(pdal_bin, "crop_corridor", f"--readers.las.filename={sample(TILE)}",
             f"--writers.las.filename={out}", f"--filters.crop.polygon={poly.wkt}")
    assert r.returncode == 0, r.stderr
    x, y, z, _ = _points(sample(TILE))
    inside = shapely.contains_xy(poly, x, y)
    gx, gy, gz, _ = _points(out)
    assert gx.size == inside.sum() > 100
    np.testing.assert_allclose(np.sort(gz), np.sort(z[inside]), atol=1e-9)
    with laspy.open(out) as f:
        crs = f.header.parse_crs()
    assert (crs.sub_crs_list[0] if crs.is_compound else crs).to_epsg() == 32617


def test_run_pipeline_errors_become_pdal_error(tmp_path: Path, pdal_bin: str) -> None:
    missing = tmp_path / "missing.laz"
    with pytest.raises(PdalError, match=r"dsm_max\.json.*missing\.laz|missing\.laz.*dsm_max"):
        run_pipeline("dsm_max", {"readers.las.filename": missing,
                                 "writers.gdal.filename": tmp_path / "x.tif"}, pdal=pdal_bin)
    bad = tmp_path / "bad.json"
    bad.write_text('{"pipeline": [{"type": "filters.nosuchstage"}]}')
    with pytest.raises(PdalError, match="bad.json"):
        run_pipeline(bad, {}, pdal=pdal_bin)
    with pytest.raises(InputError, match="stage.type.option"):
        run_pipeline("dtm", {"filename": "x"}, pdal=pdal_bin)


def test_run_pipeline_cancel_stops_pdal(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    calls = []

    def cancelled() -> bool:
        calls.append(1)
        return len(calls) > 1  # the first check (before starting) passes

    with pytest.raises(CancelledError):
        run_pipeline("dtm_smrf", {"readers.las.filename": sample("als/lasR_bcts_2.laz"),
                                  "writers.gdal.filename": tmp_path / "x.tif"},
                     pdal=pdal_bin, progress=Progress(cancelled=cancelled))
    assert not (tmp_path / "x.tif").exists()


def test_tile_info_matches_laspy_header(pdal_bin: str, sample) -> None:  # noqa: ANN001
    path = sample("als/lasR_bcts_1.laz")
    info = tile_info(path, pdal=pdal_bin)
    with laspy.open(path) as f:
        h = f.header
        assert info.n_points == h.point_count == 531662
        assert info.bounds == pytest.approx((h.mins[0], h.mins[1], h.maxs[0], h.maxs[1]),
                                            abs=1e-6)
        assert info.z_range == pytest.approx((h.mins[2], h.maxs[2]), abs=1e-6)
    pyproj = pytest.importorskip("pyproj")
    assert pyproj.CRS.from_wkt(info.horizontal_wkt).to_epsg() == 3005
    assert "Classification" in info.dimensions
    assert info.pdal_version.startswith("2.")


def test_tile_info_refuses_non_las(tmp_path: Path, pdal_bin: str) -> None:
    p = tmp_path / "x.laz"
    p.write_bytes(b"\0" * 1000)
    with pytest.raises(FileFormatError, match="x.laz"):
        tile_info(p, pdal=pdal_bin)
