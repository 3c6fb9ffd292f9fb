"""Poses and trajectories as files give them: KITTI ``poses.txt`` (12 numbers a line), TUM
(``time x y z qx qy qz qw``), one pose file a frame, a ``calib.txt``'s ``Tr``, a text file of scanner
origins, a CSV of 4 x 4 blocks. Every pose is a sensor-to-world rigid transform, float64, checked
(:data:`POSE_TOLERANCE`); bad input is refused in one line naming the file and the line.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..arrays import as_rigid_pose
from ..errors import FormatError, InputValueError, SlrWarning

__all__ = ["POSE_TOLERANCE", "read_trajectory", "trajectory_form", "read_pose_files", "read_calib_tr",
           "kitti_velodyne_poses", "write_kitti_poses", "read_origins", "read_pose_blocks", "check_pose",
           "quaternion_rotation", "frame_stamps", "STAMP_TOLERANCE"]

#: largest departure of a pose's rotation from orthonormal (|R^T R - I|, |det R - 1|): KITTI's poses
#: are written with 6-7 significant digits, whose rounding leaves ~1e-6
POSE_TOLERANCE = 1e-4


def check_pose(T, where: str) -> np.ndarray:
    """A pose read from a file, checked by :func:`slr_ray.arrays.as_rigid_pose`
    at :data:`POSE_TOLERANCE` (poses files hold 6-7 significant digits)."""
    return as_rigid_pose(T, name=where, tol=POSE_TOLERANCE)


def _numbers(path: Path, line_no: int, text: str, n: int | tuple) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split()], np.float64)
    except ValueError:
        raise InputValueError(f"{path}, line {line_no}: not numbers: {text.strip()[:80]!r}") from None
    if len(v) not in ((n,) if isinstance(n, int) else n):
        raise InputValueError(f"{path}, line {line_no}: {len(v)} numbers, expected {n}")
    return v


def _lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file") from None
    except IsADirectoryError:
        raise InputValueError(f"{path}: a directory, not a poses file") from None
    return [(i + 1, s) for i, s in enumerate(text.splitlines()) if s.strip() and not s.lstrip().startswith("#")]


def quaternion_rotation(qx, qy, qz, qw, where) -> np.ndarray:
    """The rotation of a unit quaternion; one of another norm (by more than 1e-3) is refused naming ``where``."""
    q = np.array([qw, qx, qy, qz])
    n = np.linalg.norm(q)
    if not np.isfinite(n) or abs(n - 1) > 1e-3:
        raise InputValueError(f"{where}: the quaternion's norm is {n:.6g}, not 1")
    w, x, y, z = q / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


_FORMS = {12: "12 numbers (KITTI form)", 8: "8 numbers (TUM form)"}


def trajectory_form(path) -> str:
    """``"kitti"`` (12 numbers a line) or ``"tum"`` (8) by a trajectory file's first pose line."""
    p = Path(path)
    rows = _lines(p)
    if not rows:
        raise InputValueError(f"{p}: no poses")
    return "kitti" if len(_numbers(p, rows[0][0], rows[0][1], (12, 8))) == 12 else "tum"


def read_trajectory(path, n_frames: int | None = None, stamps=None) -> np.ndarray:
    """``(n, 4, 4)`` poses from a trajectory file: KITTI form (12 numbers a line, the 3 x 4 pose
    row by row) or TUM form (8 numbers: time, x, y, z, qx, qy, qz, qw). With ``n_frames`` the
    file must hold exactly that many poses, one line a frame; unless ``stamps`` (each frame's
    time, s: its file's name) are given and a TUM file holds another number of poses: then each
    frame takes the pose of its time (:data:`STAMP_TOLERANCE`), one missing refused."""
    p = Path(path)
    rows = _lines(p)
    if stamps is not None and n_frames is not None and len(rows) != n_frames and rows \
            and trajectory_form(p) == "tum":
        return _by_time(p, rows, np.asarray(stamps, np.float64))
    if n_frames is not None and len(rows) != n_frames:
        at = f"line {rows[n_frames][0]}" if len(rows) > n_frames else f"line {rows[-1][0] + 1 if rows else 1}"
        raise InputValueError(f"{p}, {at}: {len(rows)} poses for {n_frames} frames (one line a frame)")
    out = np.empty((len(rows), 4, 4))
    first = None
    for k, (line_no, s) in enumerate(rows):
        v = _numbers(p, line_no, s, (12, 8))
        where = f"{p}, line {line_no}"
        if first is None:
            first = (line_no, len(v))
        elif len(v) != first[1]:  # one form a file: a line of the other is a file pasted onto another
            raise InputValueError(f"{where}: {_FORMS[len(v)]} where line {first[0]} is {_FORMS[first[1]]}: one "
                                  "form a trajectory file")
        if len(v) == 12:
            out[k] = check_pose(v.reshape(3, 4), where)
        else:
            if not np.all(np.isfinite(v)):
                raise InputValueError(f"{where}: the pose holds NaN or infinite numbers")
            T = np.eye(4)
            T[:3, :3] = quaternion_rotation(*v[4:], where)
            T[:3, 3] = v[1:4]
            out[k] = check_pose(T, where)
    if first is not None and first[1] == 8:
        _warn_w_first(p, rows, out)
    return out


#: a TUM trajectory read as given whose sensor z axes stray further than this from the world's z in
#: some pose, while read qw first they all stay within :data:`UPRIGHT_DEG`, is warned of (degrees)
ASTRAY_DEG, UPRIGHT_DEG = 45.0, 30.0


def _warn_w_first(p: Path, rows, poses) -> None:
    """One warning where a TUM file reads as a drive only with its quaternions taken w x y z."""
    tilt = np.degrees(np.arccos(np.clip(poses[:, 2, 2], -1, 1)))
    if tilt.max() <= ASTRAY_DEG:
        return
    q = np.array([_numbers(p, line_no, s, 8)[4:] for line_no, s in rows])  # qx qy qz qw as written
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    _, x, y, _ = q.T  # read w x y z: x, y are the 2nd and 3rd numbers
    tilt_w = np.degrees(np.arccos(np.clip(1 - 2 * (x * x + y * y), -1, 1)))
    if tilt_w.max() <= UPRIGHT_DEG:
        i = int(np.argmax(tilt))
        warnings.warn(f"{p}: line {rows[i][0]} turns its sensor's z axis {tilt[i]:.0f} deg from the world's (up to "
                      f"{tilt.max():.0f} deg); read w x y z every pose stays within {UPRIGHT_DEG:g} deg: TUM lines are "
                      "time x y z qx qy qz qw (qw last): a file written qw first?", SlrWarning, stacklevel=3)


#: the most a frame's time (its file's name) and its pose's in a TUM trajectory may differ (s)
STAMP_TOLERANCE = 1e-3


def _by_time(p: Path, rows, stamps) -> np.ndarray:
    """The poses of a TUM file at the frames' ``stamps``: each the line of the nearest time, within
    :data:`STAMP_TOLERANCE`."""
    times = np.array([_numbers(p, line_no, s, (12, 8))[0] for line_no, s in rows])
    order = np.argsort(times, kind="stable")
    ts = times[order]
    hi = np.clip(np.searchsorted(ts, stamps), 0, len(ts) - 1)
    lo = np.clip(hi - 1, 0, len(ts) - 1)
    pick = order[np.where(np.abs(ts[lo] - stamps) <= np.abs(ts[hi] - stamps), lo, hi)]
    for k, i in enumerate(pick):
        if not abs(times[i] - stamps[k]) <= STAMP_TOLERANCE:
            raise InputValueError(f"{p}: {len(rows)} poses for {len(stamps)} frames, and frame {k} (time "
                                  f"{stamps[k]:.6f} s by its name) has none within {STAMP_TOLERANCE:g} s (nearest: "
                                  f"line {rows[i][0]}, {times[i]:.6f} s)")
    return read_trajectory(p)[pick]


def read_pose_files(paths) -> np.ndarray:
    """``(n, 4, 4)`` poses, one text file a frame: a 4 x 4 or 3 x 4 matrix (rows on lines) or its
    12 or 16 numbers on one line."""
    out = np.empty((len(paths), 4, 4))
    for k, path in enumerate(paths):
        p = Path(path)
        rows = _lines(p)
        nums = [_numbers(p, line_no, s, (3, 4, 12, 16)) for line_no, s in rows]
        v = np.concatenate(nums) if nums else np.zeros(0)
        if len(v) not in (12, 16):
            raise InputValueError(f"{p}: {len(v)} numbers, expected a 4 x 4 or 3 x 4 pose (16 or 12)")
        out[k] = check_pose(v.reshape(-1, 4), f"{p}, line {rows[0][0]}")
    return out


def read_calib_tr(path) -> np.ndarray:
    """The velodyne-to-camera transform ``Tr`` of a KITTI ``calib.txt`` (4 x 4)."""
    p = Path(path)
    found = [(line_no, rest) for line_no, s in _lines(p) for key, _, rest in [s.partition(":")] if key.strip() == "Tr"]
    if not found:
        raise InputValueError(f"{p}: no 'Tr:' line (the velodyne-to-camera transform)")
    if len(found) > 1:
        raise InputValueError(f"{p}, line {found[1][0]}: a second 'Tr:' line (line {found[0][0]} is one): which is "
                              "the velodyne-to-camera transform?")
    line_no, rest = found[0]
    return check_pose(_numbers(p, line_no, rest, 12).reshape(3, 4), f"{p}, line {line_no}")


def kitti_velodyne_poses(camera_poses, Tr) -> np.ndarray:
    """Velodyne poses ``Tr^-1 P_i Tr`` from KITTI's left-camera poses ``P_i``."""
    Tr = np.asarray(Tr, np.float64)
    inv = np.linalg.inv(Tr)
    return np.einsum("ij,njk,kl->nil", inv, np.asarray(camera_poses, np.float64), Tr)


def write_kitti_poses(path, poses) -> None:
    """Poses as KITTI's ``poses.txt``: 12 numbers a line (to 1e-12 relative: %.17g)."""
    lines = [" ".join(f"{x:.17g}" for x in T[:3].ravel()) for T in np.asarray(poses, np.float64)]
    Path(path).write_text("\n".join(lines) + "\n")


def read_origins(path, n_frames: int) -> np.ndarray:
    """``(n, 3)`` scanner origins, one ``x y z`` line a frame."""
    p = Path(path)
    rows = _lines(p)
    if len(rows) != n_frames:
        raise InputValueError(f"{p}: {len(rows)} origins for {n_frames} frames (one x y z line a frame)")
    out = np.array([_numbers(p, line_no, s, 3) for line_no, s in rows]).reshape(-1, 3)
    bad = np.flatnonzero(~np.isfinite(out).all(axis=1))
    if len(bad):
        raise InputValueError(f"{p}, line {rows[bad[0]][0]}: an origin holds NaN or infinite numbers")
    return out




def read_pose_blocks(path) -> np.ndarray:
    """``(n, 4, 4)`` poses from a CSV of 4 x 4 blocks, one matrix row a line (commas or spaces; a
    trailing comma allowed): the first three rows of each block the pose, the fourth's last number
    free (a timestamp, as BALM's ``alidarPose.csv`` writes it)."""
    p = Path(path)
    rows = [(line_no, s.replace(",", " ")) for line_no, s in _lines(p)]
    if len(rows) % 4:
        raise InputValueError(f"{p}: {len(rows)} lines, not whole 4 x 4 poses (four lines a pose)")
    out = np.empty((len(rows) // 4, 4, 4))
    for k in range(len(out)):
        block = np.array([_numbers(p, line_no, s, 4) for line_no, s in rows[4 * k: 4 * k + 4]])
        out[k] = check_pose(block[:3], f"{p}, line {rows[4 * k][0]}")
    return out


def frame_stamps(paths) -> list | None:
    """Each frame's time (s) by its file's name (``1630577758.569490.pcd``), or None where a name is not
    a number."""
    out = []
    for f in paths:
        name = Path(f).name
        for suffix in Path(f).suffixes:
            name = name[: -len(suffix)] if name.endswith(suffix) and not suffix[1:].isdigit() else name
        try:
            out.append(float(name))
        except ValueError:
            return None
    return out
