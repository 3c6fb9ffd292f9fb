"""A sequence of LiDAR frames and their poses, read from the layouts real data comes in.

Two layouts:

**KITTI odometry / SemanticKITTI** (:func:`read_kitti_layout`): a directory
holding ``velodyne/NNNNNN.bin`` (numbered from 000000 without gaps), optional
``labels/NNNNNN.label`` (one uint32 a point), ``poses.txt`` (one line a frame,
12 numbers: the first three rows of the 4 x 4 pose of the *left camera* in the
world) and ``calib.txt`` whose ``Tr`` line is the velodyne-to-camera transform.
The velodyne pose of frame ``i`` is ``Tr^-1 P_i Tr``. Without ``calib.txt``
``Tr`` is the identity (the poses are the velodyne's own); a ``calib.txt``
with no ``Tr`` line is refused.

**A list of files** (:func:`read_file_list`): any format
:func:`slr_ray.io.read_cloud` reads, each frame in its own sensor's frame,
with a trajectory file in KITTI form (12 numbers a line) or TUM form
(``time x y z qx qy qz qw``), one pose a frame; or no poses at all, to be
found by registration (:func:`register_chain`).

Every pose is a sensor-to-world rigid transform, float64. Bad input is refused
before anything is read beyond the headers, each error one line naming the
file (and the line): a poses file with fewer or more lines than frames, a
non-rigid or NaN pose, a calib without Tr, gaps in frame numbers, a labels
file of another length than its frame.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..arrays import as_rigid_pose
from ..errors import FormatError, InputValueError
from ..evaluate import register
from ..io import PointCloud, read_cloud, read_e57_scans

__all__ = ["Sequence", "Frame", "read_sequence", "read_kitti_layout", "read_file_list", "read_trajectory",
           "read_calib_tr", "read_pose_files", "read_e57_sequence", "read_origins", "read_split_scans",
           "kitti_velodyne_poses", "write_kitti_poses", "register_chain", "POSE_TOLERANCE"]

#: largest departure of a pose's rotation from orthonormal (|R^T R - I|, |det R - 1|): KITTI's poses
#: are written with 6-7 significant digits, whose rounding leaves ~1e-6
POSE_TOLERANCE = 1e-4


def _pose(T, where: str) -> np.ndarray:
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
    return [(i + 1, s) for i, s in enumerate(text.splitlines()) if s.strip() and not s.lstrip().startswith("#")]


def _quaternion(qx, qy, qz, qw, where) -> np.ndarray:
    q = np.array([qw, qx, qy, qz])
    n = np.linalg.norm(q)
    if not np.isfinite(n) or abs(n - 1) > 1e-3:
        raise InputValueError(f"{where}: the quaternion's norm is {n:.6g}, not 1")
    w, x, y, z = q / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def read_trajectory(path, n_frames: int | None = None) -> np.ndarray:
    """``(n, 4, 4)`` poses from a trajectory file: KITTI form (12 numbers a line, the 3 x 4 pose
    row by row) or TUM form (8 numbers: time, x, y, z, qx, qy, qz, qw). With ``n_frames`` the
    file must hold exactly that many poses."""
    p = Path(path)
    rows = _lines(p)
    if n_frames is not None and len(rows) != n_frames:
        at = f"line {rows[n_frames][0]}" if len(rows) > n_frames else f"line {rows[-1][0] + 1 if rows else 1}"
        raise InputValueError(f"{p}, {at}: {len(rows)} poses for {n_frames} frames (one line a frame)")
    out = np.empty((len(rows), 4, 4))
    for k, (line_no, s) in enumerate(rows):
        v = _numbers(p, line_no, s, (12, 8))
        where = f"{p}, line {line_no}"
        if len(v) == 12:
            out[k] = _pose(v.reshape(3, 4), where)
        else:
            if not np.all(np.isfinite(v)):
                raise InputValueError(f"{where}: the pose holds NaN or infinite numbers")
            T = np.eye(4)
            T[:3, :3] = _quaternion(*v[4:], where)
            T[:3, 3] = v[1:4]
            out[k] = _pose(T, where)
    return out


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
        out[k] = _pose(v.reshape(-1, 4), f"{p}, line {rows[0][0]}")
    return out


def read_calib_tr(path) -> np.ndarray:
    """The velodyne-to-camera transform ``Tr`` of a KITTI ``calib.txt`` (4 x 4)."""
    p = Path(path)
    for line_no, s in _lines(p):
        key, _, rest = s.partition(":")
        if key.strip() == "Tr":
            return _pose(_numbers(p, line_no, rest, 12).reshape(3, 4), f"{p}, line {line_no}")
    raise InputValueError(f"{p}: no 'Tr:' line (the velodyne-to-camera transform)")


def kitti_velodyne_poses(camera_poses, Tr) -> np.ndarray:
    """Velodyne poses ``Tr^-1 P_i Tr`` from KITTI's left-camera poses ``P_i``."""
    Tr = np.asarray(Tr, np.float64)
    inv = np.linalg.inv(Tr)
    return np.einsum("ij,njk,kl->nil", inv, np.asarray(camera_poses, np.float64), Tr)


def write_kitti_poses(path, poses) -> None:
    """Poses as KITTI's ``poses.txt``: 12 numbers a line (to 1e-12 relative: %.17g)."""
    lines = [" ".join(f"{x:.17g}" for x in T[:3].ravel()) for T in np.asarray(poses, np.float64)]
    Path(path).write_text("\n".join(lines) + "\n")


@dataclass
class Frame:
    """One frame: points in its sensor's frame (float64), attributes, pose (sensor to world)."""

    index: int
    name: str
    points: np.ndarray
    attributes: dict
    pose: np.ndarray

    def world(self) -> np.ndarray:
        """The points in the world frame (float64)."""
        R, t = self.pose[:3, :3], self.pose[:3, 3]
        out = np.empty_like(self.points)
        for j in range(3):  # three multiply-adds a column: no BLAS threads (see union.rotate)
            out[:, j] = self.points[:, 0] * R[j, 0] + self.points[:, 1] * R[j, 1] + self.points[:, 2] * R[j, 2] + t[j]
        return out

    @property
    def origin(self) -> np.ndarray:
        return self.pose[:3, 3].copy()


@dataclass
class Sequence:
    """Frame files and their poses (``(n, 4, 4)`` sensor-to-world, float64)."""

    paths: list
    poses: np.ndarray | None
    names: list
    pose_source: str
    root: Path | None = None
    input_format: str | None = None
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.paths)

    def with_poses(self, poses, source: str) -> "Sequence":
        P = np.asarray(poses, np.float64)
        if P.shape != (len(self), 4, 4):
            raise InputValueError(f"{len(P)} poses for {len(self)} frames")
        return Sequence(self.paths, P, self.names, source, self.root, self.input_format, dict(self.meta))

    def read(self, i: int) -> Frame:
        """Frame ``i`` (points moved to its sensor's frame where the file records a scanner origin)."""
        if self.poses is None:
            raise InputValueError("the sequence has no poses: give a trajectory or register the frames")
        if self.meta.get("layout") == "e57":
            c = _e57_scans(str(self.paths[i]), os.path.getmtime(self.paths[i]))[i]
        elif "split" in self.meta:  # one file of several scans: this one's points
            whole = _whole_cloud(str(self.paths[i]), os.path.getmtime(self.paths[i]), self.input_format)
            mine = np.asarray(whole.attributes[self.meta["split"]]) == self.meta["scan_ids"][i]
            c = PointCloud(whole.points[mine], {k: np.asarray(v)[mine] for k, v in whole.attributes.items()},
                           whole.origin, dict(whole.meta))
        else:
            c = read_cloud(self.paths[i], self.input_format, allow_empty=False)
        ring = c.attributes.get("ring")
        if ring is not None and len(ring):  # one sensor a sequence: the frames' beam counts agree
            beams = int(np.max(ring)) + 1
            first = self.meta.setdefault("beams", (beams, str(self.paths[i])))
            if first[0] != beams:
                raise InputValueError(f"{self.paths[i]}: rings up to {beams - 1} ({beams} beams) where {first[1]} "
                                      f"has {first[0]}: frames of different sensors in one sequence")
        pts = c.points
        if self.meta.get("layout") == "e57":  # into the scan's own axes at its origin: R^T (p - t)
            pts = (pts - self.poses[i][:3, 3]) @ self.poses[i][:3, :3]
        elif self.meta.get("world"):  # one world frame: each frame moved to its scanner's origin
            pts = pts - self.poses[i][:3, 3]
        elif c.origin is not None and np.any(np.asarray(c.origin) != 0):
            pts = pts - np.asarray(c.origin, np.float64)
        return Frame(i, self.names[i], pts, dict(c.attributes), self.poses[i])

    def inputs(self) -> list:
        """Every file the sequence reads (frames; the planner adds their sidecars)."""
        return [Path(p) for p in self.paths] + [Path(p) for p in self.meta.get("pose_files", [])]


@lru_cache(maxsize=1)
def _e57_scans(path: str, mtime: float) -> list:
    """Every scan of an E57 file, read once a process (a window reads its scans again and again)."""
    return read_e57_scans(path)


def read_e57_sequence(path) -> Sequence:
    """The scans of one E57 file as a sequence: each scan a frame, its pose (rotation quaternion and
    translation) its frame's: a frame's points are in its scanner's own axes at its origin, as
    the scanner recorded them. A scan without a pose is refused."""
    p = Path(path)
    scans = _e57_scans(str(p), os.path.getmtime(p))
    poses = np.repeat(np.eye(4)[None], len(scans), 0)
    for i, c in enumerate(scans):
        if c.origin is None:
            raise InputValueError(f"{p}: scan {i} has no pose (no scanner origin): a sequence needs each scan's")
        poses[i, :3, 3] = c.origin
        if "e57_rotation" in c.meta:
            rot = np.column_stack([c.meta["e57_rotation"], np.zeros(3)])
            poses[i, :3, :3] = _pose(rot, f"{p}, scan {i}'s pose")[:3, :3]
    return Sequence([p] * len(scans), poses, [f"{i:06d}" for i in range(len(scans))], "e57 scan poses", None,
                    None, {"layout": "e57"})


@lru_cache(maxsize=1)
def _whole_cloud(path: str, mtime: float, input_format):
    """A file of several scans, read once a process (each frame is a part of it)."""
    return read_cloud(path, input_format, allow_empty=False)


def read_split_scans(path, field: str, origins, input_format: str | None = None) -> Sequence:
    """One file holding several scans in one world frame (a campaign's LAS/LAZ): each value of the
    per-point ``field`` (LAS ``point_source_id``, or any attribute the reader gives) a frame, in
    ascending order of the value; each scan's scanner origin a line of the text file ``origins``,
    in that order. A frame's points are moved to its origin when read (its axes the world's)."""
    p = Path(path)
    c = _whole_cloud(str(p), os.path.getmtime(p), input_format)
    if field not in c.attributes or np.ndim(c.attributes[field]) != 1:
        have = sorted(k for k, v in c.attributes.items() if np.ndim(v) == 1)
        raise InputValueError(f"{p}: no per-point field {field!r} to split its scans by (it has: "
                              f"{', '.join(have) or 'none'})")
    ids = np.unique(np.asarray(c.attributes[field]))
    poses = np.repeat(np.eye(4)[None], len(ids), 0)
    try:
        poses[:, :3, 3] = read_origins(origins, len(ids))
    except InputValueError as exc:
        raise InputValueError(f"{exc} ({p} holds {len(ids)} scans by its field {field!r})") from None
    return Sequence([p] * len(ids), poses, [f"{i:06d}" for i in range(len(ids))], "origins file", None, input_format,
                    {"world": True, "split": field, "scan_ids": ids.tolist(), "pose_files": [str(origins)]})


_NUMBERED = re.compile(r"^(\d+)\.bin$")


def _check_sizes(bins) -> None:
    for b in bins:
        if os.path.getsize(b) % 16:
            raise FormatError(f"{b}: {os.path.getsize(b)} bytes, not whole points (16 bytes a point: float32 x, y, z, "
                              "intensity): truncated, or not a KITTI .bin")


def _check_labels(bins, labels_dir: Path) -> None:
    for b in bins:
        lab = labels_dir / (b.stem + ".label")
        if lab.is_file() and os.path.getsize(lab) * 4 != os.path.getsize(b):
            raise FormatError(f"{lab}: {os.path.getsize(lab) // 4} labels for the {os.path.getsize(b) // 16} "
                              f"points of {b}")


def read_kitti_layout(root) -> Sequence:
    """A KITTI odometry / SemanticKITTI sequence directory (module docstring)."""
    root = Path(root)
    vel = root / "velodyne"
    if not vel.is_dir():
        raise InputValueError(f"{root}: no velodyne/ directory (not a KITTI sequence)")
    found = []
    for p in vel.iterdir():
        m = _NUMBERED.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    if not found:
        raise InputValueError(f"{vel}: no NNNNNN.bin frames")
    found.sort()
    for k, (num, p) in enumerate(found):
        if num != k:
            raise InputValueError(f"{p}: frame number {num} where {k} was expected (frames must be numbered "
                                  f"from 0 without gaps)")
    bins = [p for _, p in found]
    _check_sizes(bins)
    if (root / "labels").is_dir():
        _check_labels(bins, root / "labels")
    meta = {"layout": "kitti"}
    poses, source = None, "none"
    if (root / "poses.txt").is_file():
        cam = read_trajectory(root / "poses.txt", len(bins))
        Tr = read_calib_tr(root / "calib.txt") if (root / "calib.txt").is_file() else np.eye(4)
        poses = kitti_velodyne_poses(cam, Tr)
        source = "poses.txt" + (" + calib.txt Tr" if (root / "calib.txt").is_file() else "")
        meta["pose_files"] = [str(root / n) for n in ("poses.txt", "calib.txt") if (root / n).is_file()]
    return Sequence(bins, poses, [p.stem for p in bins], source, root, None, meta)


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


def read_file_list(paths, trajectory=None, input_format: str | None = None, origins=None) -> Sequence:
    """Frames from a list of files, in the order given, with an optional trajectory file, or a
    list of pose files (one a frame, :func:`read_pose_files`); or
    ``trajectory="origins"``: the files hold one world frame, each with its scanner's origin
    (each pose the translation to it; a frame's points are moved to its origin when read)."""
    files = [Path(p) for p in paths]
    if not files:
        raise InputValueError("no frames given")
    seen = {}
    for p in files:
        r = p.resolve()
        if r in seen:
            raise InputValueError(f"{p}: named twice in the sequence (as {seen[r]})")
        seen[r] = p
    poses, source, meta = None, "none", {}
    if origins is not None:  # files in one world frame (LAS/LAZ of a campaign), their origins in a text file
        if trajectory is not None:
            raise InputValueError("give the frames' poses or their origins, not both")
        poses = np.repeat(np.eye(4)[None], len(files), 0)
        poses[:, :3, 3] = read_origins(origins, len(files))
        return Sequence(files, poses, [f"{i:06d}" for i in range(len(files))], "origins file", None, input_format,
                        {"world": True, "pose_files": [str(origins)]})
    if trajectory == "origins":  # every file in one world frame, each with its scanner's origin
        poses = np.repeat(np.eye(4)[None], len(files), 0)
        for i, p in enumerate(files):
            c = read_cloud(p, input_format, allow_empty=False)
            if c.origin is None:
                raise InputValueError(f"{p}: records no scanner origin (poses 'origins' needs one in every file: "
                                      ".npz origin, .pcd VIEWPOINT, .e57 pose)")
            poses[i, :3, 3] = np.asarray(c.origin, np.float64)
        source = "origins"
        meta["world"] = True
    elif isinstance(trajectory, (list, tuple)) and len(trajectory) > 1:  # one pose file a frame
        if len(trajectory) != len(files):
            raise InputValueError(f"{len(trajectory)} pose files for {len(files)} frames (one a frame, in order)")
        poses, source = read_pose_files(trajectory), "pose files"
        meta["pose_files"] = [str(t) for t in trajectory]
    elif trajectory is not None:
        trajectory = trajectory[0] if isinstance(trajectory, (list, tuple)) else trajectory
        if trajectory == "origins":
            return read_file_list(files, "origins", input_format)
        poses, source = read_trajectory(trajectory, len(files)), "trajectory"
        meta["pose_files"] = [str(trajectory)]
    names = [f"{i:06d}" for i in range(len(files))]
    return Sequence(files, poses, names, source, None, input_format, meta)


def read_sequence(source, trajectory=None, input_format: str | None = None, origins=None,
                  scan_field: str | None = None) -> Sequence:
    """A KITTI layout directory (one path), an E57 file of several scans, or a list of frame files
    (with a trajectory, pose files, or ``origins``: a text file of each frame's scanner origin for
    files in one world frame); or one file of several scans in one world frame, split by the
    per-point ``scan_field`` with ``origins`` (:func:`read_split_scans`)."""
    src = [source] if isinstance(source, (str, os.PathLike)) else list(source)
    if scan_field is not None:
        if len(src) != 1 or origins is None or trajectory is not None:
            raise InputValueError("a scan field splits one file of several scans: give one file and --origins "
                                  "(each scan's scanner origin), no --poses")
        return read_split_scans(src[0], scan_field, origins, input_format)
    if len(src) == 1 and (Path(src[0]).is_dir() or Path(src[0]).suffix.lower() == ".e57") and origins is not None:
        raise InputValueError(f"{src[0]}: its frames carry their poses: origins are for files in one world frame")
    if len(src) == 1 and Path(src[0]).is_dir():
        if input_format is not None and str(input_format).lower().lstrip(".") != "bin":  # never ignored unsaid
            raise InputValueError(f"{src[0]}: a KITTI directory's frames are velodyne/NNNNNN.bin, read as such: "
                                  f"input_format {input_format!r} does not apply (drop it)",
                                  flags={"input_format": "--input-format"})
        seq = read_kitti_layout(src[0])
        if isinstance(trajectory, (list, tuple)):
            if len(trajectory) != 1:
                raise InputValueError(f"{src[0]}: a KITTI sequence takes one trajectory file, got {len(trajectory)}")
            trajectory = trajectory[0]
        if trajectory == "origins":
            raise InputValueError(f"{src[0]}: a KITTI sequence's frames are each in their sensor's frame: "
                                  "poses 'origins' is for files in one world frame")
        if trajectory is not None:
            seq = seq.with_poses(read_trajectory(trajectory, len(seq)), "trajectory")
            seq.meta["pose_files"] = [str(trajectory)]
        return seq
    if len(src) == 1 and Path(src[0]).suffix.lower() == ".e57" and (input_format or ".e57").lstrip(".") == "e57":
        if trajectory is not None:
            raise InputValueError(f"{src[0]}: an E57 file's scans carry their poses: no --poses")
        return read_e57_sequence(src[0])
    return read_file_list(src, trajectory, input_format, origins)


def register_chain(seq: Sequence, min_fitness: float = 0.3, progress: bool = False) -> tuple[Sequence, list]:
    """Poses by registering each frame to the one before (:func:`slr_ray.evaluate.register`),
    chained from frame 0 at the identity. Returns the sequence with those poses and each
    pair's registration (dicts)."""
    if len(seq) < 2:
        raise InputValueError("registration needs two frames or more")
    poses = [np.eye(4)]
    regs = []
    prev = seq.with_poses(np.repeat(np.eye(4)[None], len(seq), 0), "identity")
    last = prev.read(0).points
    for i in tqdm(range(1, len(seq)), desc="registering", disable=not progress):
        cur = prev.read(i).points
        reg = register(cur, last)
        if not reg.fitness >= min_fitness:
            raise InputValueError(f"{seq.paths[i]}: registered to {seq.paths[i - 1]} with fitness {reg.fitness:.3f} "
                                  f"< {min_fitness:g}: do the frames overlap? Give the poses instead")
        poses.append(poses[-1] @ reg.transform)
        regs.append(reg.to_dict() | {"frame": i, "to": i - 1})
        last = cur
    return seq.with_poses(np.stack(poses), "register"), regs
