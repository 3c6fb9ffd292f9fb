"""What a sequence is, whatever layout it came in: :class:`Sequence` (frame files, poses, and the
:class:`FrameSource` that reads them), :class:`Frame`, the registry :data:`REGISTRY` of layouts
and :func:`detect`.

A layout is a :class:`FrameSource` subclass: its ``name``, ``detect(path) -> float`` (0: not
this layout; the highest score wins, a tie is an error naming the candidates), ``open(path,
inputs) -> Sequence`` (``inputs``: what the caller gave besides the path, :class:`SequenceInputs`;
it refuses what it does not take) and, where a frame is not one file in its sensor's frame,
``frame(seq, i)``. An instance is the sequence's ``layout``, holding what the layout read once
(KITTI's ``Tr``, the scan ids of a split file).
"""

from __future__ import annotations

import dataclasses

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputTypeError, InputValueError
from ...io import read_cloud
from ...io.files import field_names
from ..poses import frame_stamps, read_trajectory

__all__ = ["Frame", "Sequence", "FrameSource", "SequenceInputs", "REGISTRY", "detect", "layout_class",
           "sensor_frame_points", "files_in", "trailing_number", "one_trajectory"]


def _natural(name: str) -> tuple:
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name) if t)


def files_in(directory, suffix: str) -> list:
    """The files of ``directory`` ending in ``suffix`` (case aside), in natural order (numbers as
    numbers: ``full9`` before ``full10``; timestamps in time order)."""
    d = Path(directory)
    if not d.is_dir():
        return []
    return sorted((p for p in d.iterdir() if p.is_file() and p.name.lower().endswith(suffix)),
                  key=lambda p: _natural(p.name))


def trailing_number(path) -> int | None:
    """The number a file's stem ends in (``full20.pcd``: 20), or None."""
    m = re.search(r"(\d+)$", Path(path).stem)
    return int(m.group(1)) if m else None


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


@dataclass(frozen=True)
class SequenceInputs:
    """What a sequence is read with besides its path(s): a trajectory (a file, pose files one a
    frame, or ``"origins"``), the frames' format, a file of scanner origins, a per-point scan field."""

    trajectory: object = None
    input_format: str | None = None
    origins: object = None
    scan_field: str | None = None

    def refuse(self, path, layout: str, *names: str, why: str = "") -> None:
        """Refuse the inputs of ``names`` given to a layout that does not take them."""
        flags = {"trajectory": "poses", "origins": "origins", "scan_field": "a scan field",
                 "input_format": "an input format"}
        given = [flags[n] for n in names if getattr(self, n) is not None]
        if given:
            raise InputValueError(f"{path}: a {layout} sequence takes no {' or '.join(given)}" + (f": {why}" if why
                                                                                                  else ""))


def one_trajectory(path, trajectory, what: str):
    """The one trajectory file a directory of frames each in its sensor's frame takes (``what``: the
    layout, "a KITTI sequence"), from ``trajectory`` (a file, or a list of one); None where none was
    given. Several files, or ``"origins"`` (files in one world frame), refused."""
    if isinstance(trajectory, (list, tuple)):
        if len(trajectory) != 1:
            raise InputValueError(f"{path}: {what} takes one trajectory file, got {len(trajectory)}")
        trajectory = trajectory[0]
    if trajectory == "origins":
        raise InputValueError(f"{path}: {what}'s frames are each in their sensor's frame: poses 'origins' is for "
                              "files in one world frame")
    return trajectory


def sensor_frame_points(cloud) -> np.ndarray:
    """A frame file's points in its sensor's frame: moved to the scanner origin the file records, if any."""
    if cloud.origin is not None and np.any(np.asarray(cloud.origin) != 0):
        return cloud.points - np.asarray(cloud.origin, np.float64)
    return cloud.points


class FrameSource:
    """A layout of frames and poses (module docstring). This base reads each path as one frame file
    in its sensor's frame (moved to the scanner origin the file records) and takes a trajectory
    as the sensor's poses."""

    #: the layout's name (``--layout``, the registry's key, errors)
    name = "frames"
    #: one line: what it is (the ambiguity error and the docs list it)
    what = "frame files, each in its sensor's frame"

    @classmethod
    def detect(cls, path) -> float:
        """How surely ``path`` is in this layout: 0 not at all; 1 sure."""
        return 0.0

    @classmethod
    def open(cls, path, inputs: SequenceInputs) -> "Sequence":
        raise NotImplementedError

    def frame(self, seq: "Sequence", i: int) -> tuple[np.ndarray, dict]:
        """Frame ``i``'s points in its sensor's frame (float64) and attributes."""
        c = read_cloud(seq.paths[i], seq.input_format, allow_empty=False)
        return sensor_frame_points(c), dict(c.attributes)

    def fields(self, seq: "Sequence", i: int) -> frozenset | None:
        """Frame ``i``'s attribute names without reading its points (its file's header), or None where
        that does not tell (:func:`slr_ray.io.files.field_names`)."""
        return field_names(seq.paths[i], seq.input_format)

    def trajectory(self, seq: "Sequence", path) -> tuple[np.ndarray, str]:
        """The poses of a trajectory file given for ``seq`` (its sensor's, one a frame) and how they
        were taken (the sequence's ``pose_source``)."""
        return read_trajectory(path, len(seq), frame_stamps(seq.paths)), "trajectory"

    def to_dict(self) -> dict:
        """What the layout read once (JSON-ready)."""
        return {}


@dataclass
class Sequence:
    """Frame files and their poses (``(n, 4, 4)`` sensor-to-world, float64), read by ``layout``
    (a :class:`FrameSource`; None: each file a frame in its sensor's frame); ``pose_files`` the
    files the poses came from (besides the frames)."""

    paths: list
    poses: np.ndarray | None
    names: list
    pose_source: str
    root: Path | None = None
    input_format: str | None = None
    layout: FrameSource | None = None
    pose_files: tuple = ()
    _beams: tuple | None = field(default=None, repr=False, compare=False)
    #: frames of more than one unit (a target sensor's held-out frames among a source's): their beam
    #: counts not checked against each other
    mixed_sensors: bool = False

    def __post_init__(self):
        if self.layout is None:
            self.layout = FrameSource()
        if not isinstance(self.layout, FrameSource):  # the seventh field was a meta dict
            raise InputTypeError(f"Sequence's layout must be a FrameSource (slr_ray.sequence.layouts), got "
                                 f"{type(self.layout).__name__}: the layout is no longer a meta dict")
        self.pose_files = tuple(str(p) for p in self.pose_files)

    def __len__(self) -> int:
        return len(self.paths)

    @property
    def meta(self) -> dict:
        """Deprecated: the layout's name, its state and the pose files as a dict (read ``layout`` and
        ``pose_files``)."""
        return {"layout": self.layout.name, **self.layout.to_dict(), "pose_files": list(self.pose_files)}

    def with_poses(self, poses, source: str, pose_files=None) -> "Sequence":
        P = np.asarray(poses, np.float64)
        if P.shape != (len(self), 4, 4):
            raise InputValueError(f"{len(P)} poses for {len(self)} frames")
        files = self.pose_files if pose_files is None else pose_files
        return Sequence(self.paths, P, self.names, source, self.root, self.input_format, self.layout, files,
                        self._beams, self.mixed_sensors)

    def of_mixed_sensors(self) -> "Sequence":
        """These frames, not checked to be of one unit (a target sensor's frames among the source's)."""
        return dataclasses.replace(self, mixed_sensors=True)

    def trajectory(self, path) -> tuple[np.ndarray, str]:
        """The sensor poses of a trajectory file given for these frames (target poses, other poses), read as
        the layout reads one (a KITTI directory's KITTI form is the camera's), and where they came from."""
        return self.layout.trajectory(self, path)

    def read(self, i: int) -> Frame:
        """Frame ``i`` in its sensor's frame."""
        if self.poses is None:
            raise InputValueError("the sequence has no poses: give a trajectory or register the frames")
        pts, attrs = self.layout.frame(self, i)
        ring = attrs.get("ring")
        if ring is not None and len(ring) and not self.mixed_sensors:  # one sensor: the frames' beam counts agree
            beams = int(np.max(ring)) + 1
            if self._beams is None:
                self._beams = (beams, str(self.paths[i]))
            if self._beams[0] != beams:
                raise InputValueError(f"{self.paths[i]}: rings up to {beams - 1} ({beams} beams) where "
                                      f"{self._beams[1]} has {self._beams[0]}: frames of different sensors in one "
                                      "sequence")
        return Frame(i, self.names[i], pts, attrs, self.poses[i])

    def inputs(self) -> list:
        """Every file the sequence reads (frames; the planner adds their sidecars)."""
        return [Path(p) for p in self.paths] + [Path(p) for p in self.pose_files]


#: name -> layout class; :func:`detect` and :func:`slr_ray.sequence.read_sequence` read it at each call
REGISTRY: dict = {}


def layout_class(name: str) -> type:
    """The layout of ``name``; an unknown one refused listing the known."""
    if name not in REGISTRY:
        raise InputValueError(f"unknown sequence layout {name!r} (known: {', '.join(REGISTRY)})")
    return REGISTRY[name]


def detect(path) -> str:
    """The name of the one layout ``path`` (a directory or a file) is in: the highest score of
    every registered layout's ``detect``. None that claims it, or two at the same score, is an
    error naming them (``layout=`` / ``--layout`` chooses)."""
    p = Path(path)
    if not os.path.exists(p):
        raise InputValueError(f"{p}: no such file or directory")
    scores = {name: float(cls.detect(p)) for name, cls in REGISTRY.items()}
    best = max(scores.values(), default=0.0)
    if not best > 0:
        kinds = "; ".join(f"{n}: {c.what}" for n, c in REGISTRY.items())
        raise InputValueError(f"{p}: not a sequence layout slr_ray knows ({kinds})")
    top = [n for n, s in scores.items() if s == best]
    if len(top) > 1:
        raise InputValueError(f"{p}: ambiguous sequence layout, it could be {' or '.join(top)} "
                              f"({'; '.join(REGISTRY[n].what for n in top)}): name one (--layout)")
    return top[0]
