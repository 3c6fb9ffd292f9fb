"""What spinning units write (#45, item 4): PCD binary_compressed and ring fields, Ouster range-image
npz, nuScenes .pcd.bin, and the 4-or-5-float ambiguity of a .bin refused rather than guessed."""

import warnings
from pathlib import Path

import numpy as np
import pytest

from slr_ray import FormatError
from slr_ray.errors import SlrNote
from slr_ray.io import PointCloud, check_format, read_cloud, write_cloud
from slr_ray.io.pcd import _lzf_decode

from conftest import DATA
SHARED_PCDS = sorted(DATA.glob("*/*.pcd"))


def _lzf_literals(raw: bytes) -> bytes:
    """A valid LZF stream of literal runs only (32 bytes at most each)."""
    out = bytearray()
    for i in range(0, len(raw), 32):
        chunk = raw[i:i + 32]
        out += bytes([len(chunk) - 1]) + chunk
    return bytes(out)


def _pcd_compressed(path, fields, n, extra=b""):
    """A binary_compressed PCD of structured ``fields`` (name -> array), column by column."""
    arrays = list(fields.values())
    kind = {"f": "F", "i": "I", "u": "U"}
    raw = b"".join(np.ascontiguousarray(a).astype(a.dtype.newbyteorder("<")).tobytes() for a in arrays)
    packed = _lzf_literals(raw) + extra
    head = "\n".join(["VERSION 0.7", "FIELDS " + " ".join(fields), "SIZE " + " ".join(str(a.itemsize) for a in arrays),
                      "TYPE " + " ".join(kind[a.dtype.kind] for a in arrays), "COUNT " + " ".join("1" for _ in arrays),
                      f"WIDTH {n}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {n}", "DATA binary_compressed"])
    Path(path).write_bytes(head.encode() + b"\n" + np.array([len(packed), len(raw)], "<u4").tobytes() + packed)


def test_lzf_back_references_overlap_as_liblzf_does():
    # "abc" as literals, then a reference 3 back of length 6 (ctrl 0b100_00000: length 4 + 2, offset 2 + 1)
    src = np.frombuffer(bytes([2]) + b"abc" + bytes([0x80, 2]), np.uint8)
    dst = np.empty(9, np.uint8)
    assert _lzf_decode(src, dst) == 9 and dst.tobytes() == b"abcabcabc"
    # a long reference (length 7 + next byte) and a reference before the start (corrupt)
    src = np.frombuffer(bytes([0]) + b"x" + bytes([0xE0, 3, 0]), np.uint8)
    dst = np.empty(13, np.uint8)
    assert _lzf_decode(src, dst) == 13 and dst.tobytes() == b"x" * 13
    assert _lzf_decode(np.frombuffer(bytes([0x80, 5]), np.uint8), np.empty(6, np.uint8)) == -1


def test_binary_compressed_pcd_reads_every_field_ring_as_int(tmp_path):
    rng = np.random.default_rng(0)
    n = 300
    fields = {"x": rng.normal(size=n).astype(np.float32), "y": rng.normal(size=n).astype(np.float32),
              "z": rng.normal(size=n).astype(np.float32), "intensity": rng.random(n).astype(np.float32),
              "ring": rng.integers(0, 64, n).astype(np.uint16), "timestamp": rng.random(n)}
    _pcd_compressed(tmp_path / "c.pcd", fields, n)
    c = read_cloud(tmp_path / "c.pcd")
    np.testing.assert_array_equal(c.points, np.column_stack([fields["x"], fields["y"], fields["z"]]))
    for k in ("intensity", "ring", "timestamp"):
        np.testing.assert_array_equal(c.attributes[k], fields[k])
        assert c.attributes[k].dtype == fields[k].dtype
    # a size that is not the header's, and corrupt data: refused, naming the file
    _pcd_compressed(tmp_path / "bad.pcd", {k: v[:-1] for k, v in fields.items()}, n)
    with pytest.raises(FormatError, match="bad.pcd.*uncompressed"):
        read_cloud(tmp_path / "bad.pcd")


def test_ascii_and_binary_pcd_keep_a_ring_field_as_integers(tmp_path):
    rng = np.random.default_rng(1)
    c = PointCloud(rng.normal(size=(50, 3)), {"laser_number": rng.integers(0, 32, 50).astype(np.uint16),
                                              "channel": rng.integers(0, 16, 50).astype(np.uint8)})
    for binary in (True, False):
        write_cloud(tmp_path / f"{binary}.pcd", c, binary=binary)
        back = read_cloud(tmp_path / f"{binary}.pcd")
        for k, v in c.attributes.items():
            np.testing.assert_array_equal(back.attributes[k], v)
            assert back.attributes[k].dtype.kind == "u"


def test_binary_pcd_zero_padding_is_no_data_but_a_lying_count_is_refused(tmp_path):
    c = PointCloud(np.arange(30.0).reshape(10, 3))
    write_cloud(tmp_path / "a.pcd", c)
    body = (tmp_path / "a.pcd").read_bytes()
    (tmp_path / "pad.pcd").write_bytes(body + bytes(4096))  # PCL pads its binary files
    np.testing.assert_array_equal(read_cloud(tmp_path / "pad.pcd").points, c.points)
    (tmp_path / "more.pcd").write_bytes(body + np.ones(6, np.float64).tobytes())
    with pytest.raises(FormatError, match="POINTS 10 declared"):
        read_cloud(tmp_path / "more.pcd")


@pytest.mark.skipif(not SHARED_PCDS, reason="../shared/data is absent")
@pytest.mark.parametrize("path", SHARED_PCDS, ids=lambda p: p.name)
def test_every_shared_pcd_reads(path):
    c = read_cloud(path)
    assert len(c) > 1000 and np.isfinite(c.points).all()
    if "ring" in c.attributes:  # Hesai's rings: integers, one per beam
        assert c.attributes["ring"].dtype.kind == "u" and c.attributes["ring"].max() < 128


def _ouster(path, rows=8, cols=16, seed=0):
    rng = np.random.default_rng(seed)
    rng_mm = rng.integers(1000, 50000, (rows, cols)).astype(np.uint32)
    rng_mm[rng.random((rows, cols)) < 0.3] = 0
    xyz = rng.normal(size=(rows, cols, 3)).astype(np.float32)
    np.savez(path, xyz=xyz, range_mm=rng_mm, reflectivity=rng.integers(0, 255, (rows, cols)).astype(np.uint8),
             col_timestamp_ns=np.arange(cols, dtype=np.uint64), beam_altitude_deg=np.linspace(10, -10, rows),
             beam_azimuth_deg=np.zeros(rows))
    return xyz, rng_mm


def test_ouster_npz_gives_points_ring_column_reflectivity_and_says_the_empty_pixels(tmp_path):
    xyz, rng_mm = _ouster(tmp_path / "o.npz")
    with pytest.warns(SlrNote, match=f"{int((rng_mm == 0).sum())} of 128 pixels have no return"):
        c = read_cloud(tmp_path / "o.npz")
    hit = rng_mm > 0
    assert len(c) == hit.sum() and c.meta["no_return_pixels"] == (~hit).sum()
    np.testing.assert_array_equal(c.points, xyz[hit])
    r, col = c.attributes["ring"], c.attributes["column"]
    assert r.dtype.kind == "i" and np.all(rng_mm[r, col] > 0)
    np.testing.assert_array_equal(c.points, xyz[r, col])
    np.testing.assert_array_equal(c.attributes["reflectivity"], c.attributes["reflectivity"])
    np.testing.assert_array_equal(c.attributes["timestamp_ns"], col)
    assert c.meta["beam_altitude_deg"][0] == 10


@pytest.mark.skipif(not (DATA / "ouster_os1_128").is_dir(), reason="../shared/data/ouster_os1_128 is absent")
def test_shared_ouster_frames_read():
    for path in sorted((DATA / "ouster_os1_128").glob("*.npz")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SlrNote)
            c = read_cloud(path)
        assert len(c) + c.meta["no_return_pixels"] == 128 * 1024 and c.attributes["ring"].max() == 127


def test_nuscenes_pcd_bin_round_trip_and_name(tmp_path):
    rng = np.random.default_rng(2)
    c = PointCloud(rng.normal(size=(16, 3)).astype(np.float32).astype(np.float64),
                   {"intensity": rng.random(16).astype(np.float32), "ring": rng.integers(0, 32, 16).astype(np.int32)})
    assert check_format(tmp_path / "n.pcd.bin") == ".pcd.bin" and check_format(tmp_path / "k.bin") == ".bin"
    write_cloud(tmp_path / "n.pcd.bin", c)
    assert (tmp_path / "n.pcd.bin").stat().st_size == 16 * 20
    back = read_cloud(tmp_path / "n.pcd.bin")
    np.testing.assert_array_equal(back.points, c.points)
    np.testing.assert_array_equal(back.attributes["ring"], c.attributes["ring"])
    assert back.attributes["ring"].dtype.kind == "i"


def test_a_five_float_frame_named_bin_is_refused_not_misread(tmp_path):
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.normal(size=(16, 4)) * 10, rng.integers(0, 32, 16)]).astype(np.float32)
    a.tofile(tmp_path / "f.bin")  # 320 bytes: 20 KITTI points or 16 nuScenes ones
    with pytest.raises(FormatError, match="nuScenes.*pcd.bin"):
        read_cloud(tmp_path / "f.bin")
    back = read_cloud(tmp_path / "f.bin", format=".pcd.bin")  # said: read as nuScenes
    assert len(back) == 16 and np.array_equal(back.attributes["ring"], a[:, 4])
    a[:3].tofile(tmp_path / "g.bin")  # 60 bytes: not KITTI's 16 a point
    with pytest.raises(FormatError, match="multiple of 20: a nuScenes"):
        read_cloud(tmp_path / "g.bin")
    k = rng.normal(size=(20, 4)).astype(np.float32)  # a KITTI frame of the same byte count still reads
    k.tofile(tmp_path / "k.bin")
    assert len(read_cloud(tmp_path / "k.bin")) == 20
