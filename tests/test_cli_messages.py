"""What a user sees: one line of our own for every error and warning (issue #40's messages)."""

import dataclasses
import errno
import sys
import warnings

import numpy as np
import pytest

from slr_ray.cli import main


@pytest.fixture
def cloud(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "in.npz"
    np.savez(path, points=np.column_stack([rng.uniform(-20, 20, (4000, 2)), rng.normal(0, 0.01, 4000)]),
             is_ground=np.ones(4000, bool))
    return path


def _err(capsys) -> list:
    return capsys.readouterr().err.strip().splitlines()


def test_a_missing_or_unknown_command_has_one_prefix_and_names_the_commands(capsys):
    assert main([]) == 2  # was 'slr-ray: error: slr-ray: the following arguments are required: cmd'
    (line,) = _err(capsys)
    assert line.startswith("slr-ray: error: a command is needed: scan, ") and "slr-ray: slr-ray" not in line
    assert main(["scene"]) == 2
    assert _err(capsys) == ["slr-ray: error: scene: a command is needed: info, build, scan (see slr-ray scene --help)"]
    assert main(["bogus"]) == 2
    (line,) = _err(capsys)
    assert line.startswith("slr-ray: error: unknown command 'bogus' (choose from 'scan'") and " cmd" not in line


def test_a_directory_as_input_is_named_as_one(tmp_path, capsys):
    for cmd in (["scan", str(tmp_path), "--origin", "0", "0", "0", "--resolution", "2", "-o", str(tmp_path / "o.npz")],
                ["augment", str(tmp_path), "--n", "1", "-o", str(tmp_path / "aug")]):
        assert main(cmd) == 2  # was "unknown point-cloud format '.'"
        assert _err(capsys) == [f"slr-ray: error: {tmp_path} is a directory, not a point-cloud file"]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_file_named_with_a_trailing_slash_is_refused_not_written_without_it(cloud, tmp_path, capsys):
    scan = ["scan", "--origin", "0", "0", "1", "--resolution", "2", "--quiet"]
    for path in ("ts.npz/", "ts.npz/."):
        assert main([*scan, str(cloud), "-o", f"{tmp_path}/{path}"]) == 2  # was: a file ts.npz written
        (line,) = _err(capsys)
        assert line.startswith(f"slr-ray: error: {tmp_path}/{path}: a path ending in '/' names a directory")
    assert main([*scan, f"{cloud}/", "-o", str(tmp_path / "o.npz")]) == 2  # an input too (the system's rule)
    assert "names a directory" in _err(capsys)[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [cloud.name]


@pytest.mark.parametrize("fmt, failure", [
    (".npz", OSError(errno.EFBIG, "File too large")),        # Python's write: an errno, no file name
    (".bin", OSError("76468 requested and 1024 written")),  # numpy's tofile: not even an errno
])
def test_a_write_that_runs_out_of_room_names_the_file_and_leaves_nothing(cloud, tmp_path, capsys, monkeypatch,
                                                                       fmt, failure):
    # was 'slr-ray: error: [Errno 27] File too large': which file, of a run's many?
    from slr_ray.io import REGISTRY

    def full(path, *a):
        with open(path, "wb") as f:
            f.write(b"x" * 10)
        raise failure

    monkeypatch.setitem(REGISTRY, fmt, dataclasses.replace(REGISTRY[fmt], write=full))
    out = tmp_path / f"o{fmt}"
    assert main(["scan", str(cloud), "--origin", "0", "0", "1", "--resolution", "2", "--quiet", "-o", str(out)]) == 2
    (line,) = _err(capsys)
    assert line.startswith(f"slr-ray: error: ") and f"cannot write {out}: " in line
    assert sorted(p.name for p in tmp_path.iterdir()) == [cloud.name]


def test_warnings_reach_the_terminal_as_one_line_of_ours(cloud, tmp_path, capsys):
    # was "/.../commands.py:123: UserWarning: ..." and the source line under it
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = (lambda m, c, f, n, file=None, line=None:  # as Python's own, at a terminal
                                sys.stderr.write(warnings.formatwarning(m, c, f, n, line)))
        assert main(["scan", str(cloud), "--origin", "0", "0", "1", "--resolution", "2", "--quiet", "-o",
                     str(tmp_path / "o.bin")]) == 0
    assert _err(capsys) == [f"slr-ray: warning: {tmp_path / 'o.bin'}: KITTI .bin holds x, y, z and intensity "
                            "only; not written: ['is_ground']"]
    assert warnings.formatwarning.__name__ == "formatwarning"  # restored on the way out
    # a caller of main() that records warnings (pytest, catch_warnings) still gets them whole
    with pytest.warns(UserWarning, match="not written: \\['is_ground'\\]"):
        assert main(["scan", str(cloud), "--origin", "0", "0", "1", "--resolution", "2", "--quiet", "--force",
                     "-o", str(tmp_path / "o.bin")]) == 0


def test_a_workers_warnings_are_said_by_the_parent(cloud, tmp_path):
    # each worker process printed Python's warning text itself, past any hook of the command's
    from slr_ray.augment import AugmentConfig, augment

    with pytest.warns(UserWarning) as said:
        augment(cloud, tmp_path / "aug", AugmentConfig(n=2, resolution=2.0, min_ground_points=10, workers=2,
                                                       fmt=".bin"), progress=False)
    # said by the parent, once for the scans that gave it, with their count
    (w,) = [str(w.message) for w in said if "is_ground" in str(w.message)]
    assert w.startswith(str(tmp_path / "aug" / "scan_*.bin") + ":") and w.endswith("(in 2 scans)"), w
