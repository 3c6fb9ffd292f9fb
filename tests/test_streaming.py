"""Streamed LAS/LAZ scans equal whole-file scans: indices, records, header."""

import numpy as np
import pytest

from slr_ray import simulate_scan
from slr_ray.errors import FormatError
from slr_ray.io import PointCloud, read_cloud, write_cloud
from slr_ray.streaming import scan_las, scan_las_many


@pytest.fixture(scope="module")
def las_file(tmp_path_factory):
    rng = np.random.default_rng(0)
    n = 50_000
    pts = np.column_stack([rng.uniform(-30, 30, (n, 2)), rng.normal(0, 0.05, n)]) + [6e5, 5e6, 100]
    path = tmp_path_factory.mktemp("s") / "in.laz"
    write_cloud(path, PointCloud(pts, {"classification": rng.integers(0, 8, n).astype(np.uint8),
                                       "gps_time": rng.uniform(0, 1e4, n)}))
    return path


# 61: many tiny chunks, each shorter than a 64-point word of the tables' bitmap and not dividing
# it (61 is prime to 64, so the adds start at every offset within a word and a word holds winners
# of two or three chunks; 820 chunks of the 50,000 points)
@pytest.mark.parametrize("chunk", [61, 997, 50_000, 10**7])
def test_streamed_scan_equals_the_whole_file_scan(las_file, tmp_path, chunk):
    import laspy

    origin = [6e5 + 1.5, 5e6 - 2.0, 101.7]
    whole = read_cloud(las_file)
    want = simulate_scan(whole.points, origin, 0.5)
    cloud, scan = scan_las(las_file, origin, 0.5, chunk=chunk)
    np.testing.assert_array_equal(scan.indices, want.indices)
    np.testing.assert_array_equal(scan.ranges, want.ranges)
    np.testing.assert_array_equal(cloud.points, whole.points[want.indices])
    for k, v in whole.attributes.items():
        np.testing.assert_array_equal(cloud.attributes[k], v[want.indices])
    write_cloud(tmp_path / "a.laz", cloud)
    write_cloud(tmp_path / "b.laz", whole.subset(want.indices))
    a, b = laspy.read(str(tmp_path / "a.laz")), laspy.read(str(tmp_path / "b.laz"))
    np.testing.assert_array_equal(a.points.array, b.points.array)
    assert str(a.header.version) == str(b.header.version)


def test_streamed_scans_of_several_origins_read_the_file_once(las_file, las_reads, table_kind):
    # one pass of 997-point chunks feeds every origin's reduction; each scan equals the
    # whole-file scan (indices, ranges, coordinates, attributes, raw records)
    origins = [[6e5 + 1.5, 5e6 - 2.0, 101.7], [6e5 - 10, 5e6 + 3.0, 100.5], [6e5 + 25, 5e6 + 25, 102.0],
               [6e5, 5e6, 100.01]]
    whole = read_cloud(las_file)
    got = list(scan_las_many(las_file, origins, 0.5, chunk=997, n_threads=2))
    assert las_reads == [len(whole)]
    assert len(got) == len(origins)
    for (cloud, scan), origin in zip(got, origins):
        want = simulate_scan(whole.points, origin, 0.5)
        assert len(want) > 1000
        np.testing.assert_array_equal(scan.indices, want.indices)
        np.testing.assert_array_equal(scan.ranges, want.ranges)
        np.testing.assert_array_equal(cloud.points, whole.points[want.indices])
        for k, v in whole.attributes.items():
            np.testing.assert_array_equal(cloud.attributes[k], v[want.indices])
        np.testing.assert_array_equal(cloud.meta["las"].array, whole.meta["las"].array[want.indices])


def test_streamed_scan_reads_the_file_once(las_file, las_reads):
    cloud, scan = scan_las(las_file, [6e5, 5e6, 101.0], 0.5, chunk=4999)
    assert las_reads == [len(read_cloud(las_file))] and len(scan) > 1000


def test_streamed_scan_refuses_other_formats_and_bad_files(tmp_path):
    with pytest.raises(FormatError):
        scan_las(tmp_path / "x.ply", [0, 0, 0], 1.0)
    with pytest.raises(FileNotFoundError):
        scan_las(tmp_path / "x.las", [0, 0, 0], 1.0)
    (tmp_path / "bad.las").write_bytes(b"LASF" + b"\0" * 50)
    with pytest.raises(FormatError):
        scan_las(tmp_path / "bad.las", [0, 0, 0], 1.0)


def test_cli_scan_streams_las(las_file, tmp_path, capsys):
    import json

    from slr_ray.cli import main

    out = tmp_path / "o.laz"
    assert main(["scan", str(las_file), "--origin", "600001.5", "4999998", "101.7", "--resolution", "0.5",
                 "--chunk-size", "5000", "--quiet", "-o", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["streamed"] and res["points_out"] == len(read_cloud(out))


def test_cli_scan_of_las_with_a_sensor_reads_it_whole(las_file, tmp_path, capsys):
    import json

    from slr_ray.cli import main

    out = tmp_path / "os1.laz"
    assert main(["scan", str(las_file), "--sensor", "ouster_os1_64", "--origin", "600001.5", "4999998", "101.7",
                 "--keep-ring", "--quiet", "-o", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert not res["streamed"] and res["points_out"] > 0
    back = read_cloud(out)
    assert "ring" in back.attributes and back.attributes["ring"].max() < 64
