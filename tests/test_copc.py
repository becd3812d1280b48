"""Cloud-optimised surveys (COPC files, EPT datasets) read by an area's octree nodes only.

The COPC file and the EPT dataset are made here from the two bundled BC tiles
(``tests/copc_data.py``: an octree of nodes of at most 5,000 points, hierarchy pages /
sub-hierarchy files below level 2 so a reader must follow them).  The independent truths:
the tiles read with ``read_las`` and cropped here by brute force (a corridor's rotated
rectangle tested by its own along/across distances), laspy's own ``CopcReader``, and PDAL's
``readers.ept``.  Remote reads go to real servers on the loopback address
(``tests/loopback_servers.py``); the bytes are counted by the server.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import FileFormatError, InputError, NoUsableDataError
from canopyblocks.readers import remote
from canopyblocks.readers.copc import copc_extent, read_copc
from canopyblocks.readers.ept import ept_extent, read_ept
from canopyblocks.readers.las import LasPoints, read_las
from copc_data import build_octree, tile_points, write_copc, write_ept
from loopback_servers import RangeHTTPServer, S3Server, use_s3_server

TILES = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
BOX = (885100.0, 629200.0, 885130.0, 629400.0)
# a track crossing the survey (195 m x 543 m) east-west, 8 degrees off, corridor 20 m wide
TRACK = {"x0": 885120.0, "y0": 629250.0, "angle": math.radians(8.0), "length": 400.0,
         "width": 20.0}


def corridor_polygon() -> object:
    import shapely

    t = TRACK
    ux, uy = math.cos(t["angle"]), math.sin(t["angle"])
    a, w = t["length"] / 2, t["width"] / 2
    corners = [(t["x0"] + sa * a * ux - sw * w * uy, t["y0"] + sa * a * uy + sw * w * ux)
               for sa, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return shapely.Polygon(corners)


def in_corridor(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Brute force, without shapely: along/across distances from the track's centre line
    (strictly inside by 1 mm, so no point sits on the edge where rounding would decide)."""
    t = TRACK
    dx, dy = x - t["x0"], y - t["y0"]
    along = dx * math.cos(t["angle"]) + dy * math.sin(t["angle"])
    across = -dx * math.sin(t["angle"]) + dy * math.cos(t["angle"])
    return (np.abs(along) <= t["length"] / 2) & (np.abs(across) <= t["width"] / 2)


def table(p: LasPoints) -> np.ndarray:
    """The points as rows (x, y, z, class, return, returns), sorted: an order-free compare."""
    rows = np.column_stack([p.x, p.y, p.z, p.classification, p.return_number,
                            p.number_of_returns])
    return rows[np.lexsort(rows.T[::-1])]


@pytest.fixture(scope="module")
def tiles(sample) -> list[Path]:
    return [sample(t) for t in TILES]


@pytest.fixture(scope="module")
def laz(tiles) -> LasPoints:
    return read_las(tiles)


@pytest.fixture(scope="module")
def store(tmp_path_factory, tiles) -> Path:
    """survey.copc.laz and ept/ (the same octree), under one folder a server can serve."""
    root = tmp_path_factory.mktemp("cloud")
    tree = build_octree(tile_points(tiles), capacity=5000)
    write_copc(tiles, root / "survey.copc.laz", tree=tree, page_level=2)
    write_ept(tiles, root / "ept", tree=tree, split_level=2)
    (root / "norange").mkdir()
    shutil.copy(root / "survey.copc.laz", root / "norange" / "survey.copc.laz")
    return root


@pytest.fixture(scope="module")
def http(store):
    with RangeHTTPServer(store) as server:
        yield server


def test_copc_corridor_is_the_laz_cropped(store, laz):
    got = read_copc(store / "survey.copc.laz", polygon=corridor_polygon())
    want = laz.subset(in_corridor(laz.x, laz.y))
    assert len(want) > 20_000
    np.testing.assert_array_equal(table(got), table(want))  # bit for bit
    assert got.crs.equals(laz.crs) and got.vertical_datum == laz.vertical_datum == "EPSG:5713"


def test_copc_box_agrees_with_laspy_copc_reader(store, laz):
    # the oracle: laspy's own COPC reader, whose box query returns too many points in laspy
    # 2.4 (71,718 for 67,265 in the box; 2.5.3 agrees with the brute force)
    laspy = pytest.importorskip("laspy", minversion="2.5.3")

    got = read_copc(str(store / "survey.copc.laz"), bounds=BOX)
    keep = (laz.x >= BOX[0]) & (laz.x <= BOX[2]) & (laz.y >= BOX[1]) & (laz.y <= BOX[3])
    np.testing.assert_array_equal(table(got), table(laz.subset(keep)))
    with laspy.CopcReader.open(str(store / "survey.copc.laz")) as reader:
        q = reader.query(bounds=laspy.copc.Bounds(np.array(BOX[:2]), np.array(BOX[2:])))
    assert len(q) == len(got) == int(keep.sum())
    np.testing.assert_array_equal(np.sort(np.asarray(q.x)), np.sort(got.x))


def test_copc_whole_file_and_extent(store, laz, tiles):
    import laspy

    ext = copc_extent(store / "survey.copc.laz")
    assert ext.n_points == len(laz) == 1_355_607
    heads = []
    for t in tiles:
        with laspy.open(t) as reader:
            heads.append(reader.header)
    want = (min(h.mins[0] for h in heads), min(h.mins[1] for h in heads),
            max(h.maxs[0] for h in heads), max(h.maxs[1] for h in heads))
    np.testing.assert_allclose(ext.bounds, want, atol=1e-6)
    assert ext.crs is not None and ext.crs.to_epsg() == 3005
    np.testing.assert_array_equal(table(read_copc(store / "survey.copc.laz")), table(laz))


def test_copc_over_https_same_points_fewer_bytes(store, http, laz):
    remote.clear_cache()
    http.tally.reset()
    size = (store / "survey.copc.laz").stat().st_size
    got = read_copc(f"{http.url}/survey.copc.laz", polygon=corridor_polygon())
    local = read_copc(store / "survey.copc.laz", polygon=corridor_polygon())
    np.testing.assert_array_equal(table(got), table(local))
    fraction = http.tally.nbytes / size
    assert 0.01 < fraction < 0.20, f"{fraction:.1%} of the file fetched for a crossing track"
    assert http.tally.range_requests == http.tally.requests


def test_footprint_reference_from_https_copc_is_the_tiles(store, http, laz):
    """13 m footprints every 15 m along the crossing track: the reference values from the
    COPC over http:// equal those from the LAZ tiles (the same corridor cropped)."""
    from canopyblocks.reference.footprint import footprint_reference

    t = TRACK
    along = np.arange(-90.0, 90.0, 15.0)  # inside the survey (x 885022-885217)
    fx = t["x0"] + along * math.cos(t["angle"])
    fy = t["y0"] + along * math.sin(t["angle"])
    remote.clear_cache()
    got = footprint_reference(read_copc(f"{http.url}/survey.copc.laz",
                                        polygon=corridor_polygon()), fx, fy)
    want = footprint_reference(laz.subset(in_corridor(laz.x, laz.y)), fx, fy)
    assert (got["ref_flag"] == want["ref_flag"]).all() and len(got) == 12
    num = [c for c in want.columns if want[c].dtype.kind == "f"]
    assert np.isfinite(want[num].to_numpy()).any()
    np.testing.assert_allclose(got[num].to_numpy(), want[num].to_numpy(), atol=1e-9,
                               equal_nan=True)


def test_copc_over_s3(store, laz, monkeypatch, tmp_path):
    with S3Server() as s3:
        url = s3.put("surveys", "bc/survey.copc.laz", store / "survey.copc.laz")
        use_s3_server(monkeypatch, s3.endpoint, tmp_path)
        remote.clear_cache()
        got = read_copc(url, bounds=BOX)
        assert s3.tally.nbytes < 0.2 * (store / "survey.copc.laz").stat().st_size
        ext = copc_extent(url)
        with pytest.raises(FileFormatError, match=r"s3://surveys/bc/gone.copc.laz: not found"):
            read_copc("s3://surveys/bc/gone.copc.laz", bounds=BOX)
    keep = (laz.x >= BOX[0]) & (laz.x <= BOX[2]) & (laz.y >= BOX[1]) & (laz.y <= BOX[3])
    np.testing.assert_array_equal(table(got), table(laz.subset(keep)))
    assert ext.n_points == len(laz) and ext.source == url


def test_ept_local_and_https_are_the_laz_cropped(store, http, laz):
    want = laz.subset(in_corridor(laz.x, laz.y))
    local = read_ept(store / "ept" / "ept.json", polygon=corridor_polygon())
    np.testing.assert_array_equal(table(local), table(want))
    assert local.vertical_datum == "EPSG:5713" and local.crs.equals(laz.crs)
    remote.clear_cache()
    http.tally.reset()
    got = read_ept(f"{http.url}/ept/ept.json", polygon=corridor_polygon())
    np.testing.assert_array_equal(table(got), table(want))
    total = sum(p.stat().st_size for p in (store / "ept").rglob("*") if p.is_file())
    assert http.tally.nbytes < 0.25 * total
    ext = ept_extent(f"{http.url}/ept")
    assert ext.n_points == len(laz) and ext.crs is not None and ext.crs.to_epsg() == 3005


def test_ept_box_agrees_with_pdal(store, pdal_bin, tmp_path):
    got = read_ept(store / "ept" / "ept.json", bounds=BOX)
    pipe = {"pipeline": [{"type": "readers.ept", "filename": str(store / "ept" / "ept.json"),
                          "bounds": f"([{BOX[0]},{BOX[2]}],[{BOX[1]},{BOX[3]}])"},
                         {"type": "filters.stats", "dimensions": "X,Y"}]}
    (tmp_path / "p.json").write_text(json.dumps(pipe))
    subprocess.run([pdal_bin, "pipeline", str(tmp_path / "p.json"), "--metadata",
                    str(tmp_path / "m.json")], check=True, capture_output=True)
    stats = json.loads((tmp_path / "m.json").read_text())["stages"]["filters.stats"]["statistic"]
    x = next(s for s in stats if s["name"] == "X")
    assert x["count"] == len(got)
    assert x["average"] == pytest.approx(float(got.x.mean()), abs=1e-4)  # PDAL prints 4 places
    assert (x["minimum"], x["maximum"]) == (float(got.x.min()), float(got.x.max()))


def test_ept_over_s3_fetches_only_the_nodes_it_needs(store, laz, monkeypatch, tmp_path):
    """Only the hierarchy files and nodes the corridor needs are in the bucket: a request for
    any other would be a 404 and fail the read."""
    from canopyblocks.readers.copc import Area
    from canopyblocks.readers.ept import EptInfo, select_nodes

    ept = store / "ept"
    nodes = select_nodes(EptInfo(str(ept / "ept.json")), Area(None, corridor_polygon()))
    needed = ["ept.json", *(f"ept-hierarchy/{p.name}" for p in (ept / "ept-hierarchy").iterdir()),
              *(f"ept-data/{'-'.join(map(str, k))}.laz" for k, _ in nodes)]
    assert len(nodes) < len(list((ept / "ept-data").iterdir())) / 3
    with S3Server() as s3:
        for rel in needed:
            s3.put("surveys", f"ept/{rel}", ept / rel)
        use_s3_server(monkeypatch, s3.endpoint, tmp_path)
        remote.clear_cache()
        got = read_ept("s3://surveys/ept/ept.json", polygon=corridor_polygon())
    np.testing.assert_array_equal(table(got), table(laz.subset(in_corridor(laz.x, laz.y))))


def test_cancel_stops_fetching(store, http, monkeypatch):
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress
    from canopyblocks.readers import copc

    monkeypatch.setattr(copc, "BATCH_POINTS", 50_000)
    remote.clear_cache()
    http.tally.reset()
    calls: list[float] = []
    prog = Progress(lambda f, m: calls.append(f), cancelled=lambda: len(calls) >= 2)
    with pytest.raises(CancelledError):
        read_copc(f"{http.url}/survey.copc.laz", progress=prog)
    assert len(calls) == 2 and calls[-1] < 0.2
    assert http.tally.nbytes < 0.2 * (store / "survey.copc.laz").stat().st_size


def test_progress_and_no_points(store):
    seen: list[float] = []
    read_copc(store / "survey.copc.laz", bounds=BOX, progress=lambda f, m: seen.append(f))
    assert seen and seen[-1] == pytest.approx(1.0)
    with pytest.raises(NoUsableDataError, match="survey.copc.laz: no points inside bounds"):
        read_copc(store / "survey.copc.laz", bounds=(0, 0, 10, 10))
    with pytest.raises(InputError, match="bounds must be"):
        read_copc(store / "survey.copc.laz", bounds=(1, 2, 0, 3))


def test_a_copc_written_by_pdal_decodes_as_laspy_reads_it(sample):
    """A COPC file another writer made (PDAL, point format 7 with colour, 36-byte records,
    hierarchy pages): every node and a quarter's nodes give laspy's points; the file's
    heights are in US survey feet, refused as a LAZ tile's are."""
    import laspy

    from canopyblocks.errors import CRSError
    from canopyblocks.readers import copc

    path = sample("copc/simple_with_page.copc.laz")
    ref = laspy.read(path)
    with copc.ByteSource(path) as src:
        h = copc.read_header(src)
        assert (h.point_format, h.record_length, h.n_points) == (7, 36, 1065)
        b = h.bounds
        for box in (None, (b[0], b[1], (b[0] + b[2]) / 2, (b[1] + b[3]) / 2)):
            area = copc.Area(box, None)
            cols = copc.Columns(h.label)
            nodes = copc.select_nodes(src, h, area)
            for batch in copc._batches(nodes):
                blobs = src.fetch([(n[1], n[1] + n[2]) for n in batch])
                cols.add(copc._decompress(h, blobs, batch), h.scales, h.offsets, area)
            got = LasPoints(*(np.concatenate(cols.parts[k]) for k in "xyzcrn"), crs=None)
            x, y = np.asarray(ref.x), np.asarray(ref.y)
            keep = np.ones(x.size, bool) if box is None else (
                (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3]))
            want = LasPoints(x[keep], y[keep], np.asarray(ref.z)[keep],
                             np.asarray(ref.classification)[keep],
                             np.asarray(ref.return_number)[keep],
                             np.asarray(ref.number_of_returns)[keep], crs=None)
            assert len(got) == int(keep.sum()) > 200
            np.testing.assert_array_equal(table(got), table(want))
        assert len(nodes) < 65
    with pytest.raises(CRSError, match="US survey foot"):
        read_copc(path)


# ---- bad inputs: one line naming the source and what to do -----------------------------------

def _one_line(exc: pytest.ExceptionInfo, *words: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and "Traceback" not in msg
    assert any(w in msg for w in words), msg
    return msg


def test_truncated_copc(store, tmp_path):
    raw = (store / "survey.copc.laz").read_bytes()
    for frac in (0.001, 0.3, 0.9, 0.999):
        p = tmp_path / f"cut{frac}.copc.laz"
        p.write_bytes(raw[:int(len(raw) * frac)])
        with pytest.raises(FileFormatError) as exc:
            read_copc(p, bounds=BOX)
        assert p.name in _one_line(exc, "truncated", "not a COPC", "corrupt")


def test_laz_that_is_not_copc(tiles):
    with pytest.raises(FileFormatError) as exc:
        read_copc(tiles[0])
    assert "lasR_bcts_1.laz" in _one_line(exc, "not a COPC file")


def test_broken_ept(store, tmp_path):
    ept = tmp_path / "ept"
    shutil.copytree(store / "ept", ept)
    meta = (ept / "ept.json").read_text()
    (ept / "ept.json").write_text(meta[: len(meta) // 2])
    with pytest.raises(FileFormatError) as exc:
        ept_extent(ept / "ept.json")
    _one_line(exc, "not valid JSON")
    (ept / "ept.json").write_text(meta.replace('"laszip"', '"binary"'))
    with pytest.raises(FileFormatError) as exc:
        read_ept(ept)
    _one_line(exc, "'binary' is not supported")
    (ept / "ept.json").write_text(meta)
    node = sorted((ept / "ept-data").glob("3-*.laz"))[0]
    node.unlink()
    with pytest.raises(FileFormatError) as exc:
        read_ept(ept / "ept.json")
    assert node.name in _one_line(exc, "is missing")


def test_server_without_ranges(store, http):
    remote.clear_cache()
    with pytest.raises(FileFormatError) as exc:
        read_copc(f"{http.url}/norange/survey.copc.laz", bounds=BOX)
    assert "norange/survey.copc.laz" in _one_line(exc, "byte-range")


def test_short_answers_for_a_survey_say_the_file_not_a_granule(tmp_path, store,
                                                                monkeypatch):
    """A COPC answered short over http: the advice fits a survey (download the file),
    with no word borrowed from the photon-file reader."""
    monkeypatch.setattr(remote, "RETRIES", 1)
    monkeypatch.setattr(remote, "BACKOFF", 0.0)
    (tmp_path / "short").mkdir()
    shutil.copy(store / "survey.copc.laz", tmp_path / "short" / "survey.copc.laz")
    with RangeHTTPServer(tmp_path) as server:
        remote.clear_cache()
        with pytest.raises(FileFormatError) as exc:
            read_copc(f"{server.url}/short/survey.copc.laz", bounds=BOX)
    line = _one_line(exc, "the server's answers were short")
    assert line.endswith("run again later, or download the file and pass the local copy")
    assert "granule" not in line


def test_small_node_copc_fetches_about_the_nodes_it_needs(tmp_path, tiles, laz, monkeypatch):
    """Nodes of at most 300 points (a few kB each): a corridor fetches the nodes it needs
    and not the file between them (gaps are merged up to half the median node, not 64 KiB);
    the same points as the local file."""
    from canopyblocks.readers import copc

    tree = build_octree(tile_points(tiles), capacity=300, max_level=10)
    path = tmp_path / "small.copc.laz"
    write_copc(tiles, path, tree=tree)
    with copc.ByteSource(path) as src:
        h = copc.read_header(src)
        nodes = copc.select_nodes(src, h, copc.Area(None, corridor_polygon()))
    needed = sum(n[2] for n in nodes)
    size = path.stat().st_size
    assert len(nodes) > 100 and needed < 0.4 * size
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "10")  # a stalled connection retried sooner
    with RangeHTTPServer(tmp_path) as server:
        remote.clear_cache()
        server.tally.reset()
        got = read_copc(f"{server.url}/small.copc.laz", polygon=corridor_polygon())
        # the ranges the reader asked for: a range the transport asks again after a stalled
        # connection (an intermittent stall on loopback, retried) is not the gap logic's cost
        fetched = server.tally.distinct_bytes
    np.testing.assert_array_equal(table(got), table(read_copc(path, polygon=corridor_polygon())))
    assert fetched < 2.0 * needed + 200_000, (fetched / size, needed / size)
    assert copc.node_gap([(0, 4000), (9000, 12000), (20000, 90000)]) == 2000
    assert copc.node_gap([(0, 1 << 20)] * 3) == remote.MAX_GAP
