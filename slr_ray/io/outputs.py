"""Every file a command touches, checked before the work: :class:`OutputPlan`.

A command lists what it reads (the input, its sidecars such as a
SemanticKITTI ``.label``, sensor files, profiles, configs) and what it will
write (clouds and their sidecars, range images, PNGs, JSON, output
directories), then enters the plan. The plan

- resolves relative paths and links: an output that is a symbolic link is
  written *through* (the link stays, the file it points to is replaced, as
  ``cp`` and ``open(path, "w")`` do); an output that exists and is not a
  regular file (a directory, a device, a FIFO) is refused;
- refuses two outputs that are one file, and any output that is an input
  (by resolved path, or by device and inode: a hard link), with ``--force``
  too;
- refuses an existing output unless ``force``;
- refuses an output whose directory (or the nearest existing parent of an
  output directory to create) this process cannot write, and runs each
  output's own check (its format: a figure format matplotlib cannot write,
  a point-cloud format slr_ray cannot write), so that such a run stops
  before the work, not after it;
- locks every output directory (``.slr_ray.lock``, an advisory ``flock``,
  released by the kernel when the process dies, even by ``kill -9``), so two
  runs into one directory cannot both proceed; a single file is not written
  into a directory another run holds (a shared lock on its lock file, where
  there is one);
- removes the ``.part`` temporaries that a killed run left beside its
  outputs (:func:`slr_ray.io.atomic_path` names them with the writer's host
  and process id; those of a process still alive are left alone);
- on an error, removes the directories it created, if they hold nothing.

:func:`content_digest` is the identity of an input that resumes compare.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import os
import re
import socket
import stat
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError

__all__ = ["OutputPlan", "resolve", "output_sidecars", "input_sidecars", "label_targets", "content_digest",
           "clean_stale_parts", "part_prefix", "label_path", "label_destinations", "link_new", "hold_directory",
           "LOCK_NAME"]

#: The lock file in an output directory while a command writes there.
LOCK_NAME = ".slr_ray.lock"


def resolve(path) -> Path:
    """``path`` absolute, ``~`` expanded and every symbolic link followed
    (a dangling link: the path it points to)."""
    return Path(os.path.realpath(os.path.abspath(os.path.expanduser(os.fspath(path)))))


def output_sidecars(path, fmt: str | None = None) -> list:
    """The files :func:`slr_ray.io.write_cloud` writes (or removes) beside ``path``
    written as ``fmt`` (default: its extension): a KITTI ``.bin``'s SemanticKITTI
    ``.label`` (:func:`label_targets`)."""
    p = Path(path)
    ext = (fmt or p.suffix).lower()
    return label_targets(p) if ext in (".bin", "bin") else []


def _layout_label(p: Path) -> Path | None:
    """``SEQ/labels/NAME.label`` for ``SEQ/velodyne/NAME.bin`` (the SemanticKITTI layout), else None."""
    return p.parent.parent / "labels" / (p.stem + ".label") if p.parent.name == "velodyne" else None


def _named_label_targets(p: Path) -> list:
    beside, layout = p.with_suffix(".label"), _layout_label(p)
    if layout is not None and layout.parent.is_dir():
        return [layout, beside]
    return [beside]


def label_destinations(bin_path) -> list:
    """Where :func:`slr_ray.io.write_cloud` writes the labels of a KITTI ``.bin``:
    where a reader of ``bin_path`` looks first and, for a ``bin_path`` that is a
    symbolic link (written through), where a reader of the file it points to
    looks first too (else that file's old labels would stay paired with its new
    points)."""
    p = Path(bin_path)
    out = [_named_label_targets(p)[0]]
    if p.is_symlink():
        real = _named_label_targets(resolve(p))[0]
        if resolve(real) != resolve(out[0]):
            out.append(real)
    return out


def label_targets(bin_path) -> list:
    """Where :func:`slr_ray.io.write_cloud` puts the labels of a KITTI ``.bin``
    (:func:`label_destinations`, first), and every other place a reader would
    look for them: a stale file there is removed (it would be paired with the
    new points). In the SemanticKITTI layout (``velodyne/`` beside an existing
    ``labels/``) the labels go to ``labels/``. A ``.bin`` that is a symbolic
    link adds the places beside the file it points to."""
    p = Path(bin_path)
    targets = label_destinations(p) + _named_label_targets(p)
    if p.is_symlink():
        targets += _named_label_targets(resolve(p))
    out, seen = [], set()
    for t in targets:  # one path per file: a .label that is a link to another is one target
        r = resolve(t)
        if r not in seen:
            seen.add(r)
            out.append(t)
    return out


def label_path(bin_path) -> Path | None:
    """The SemanticKITTI ``.label`` file of a KITTI ``.bin``, if there is one: next
    to it (``000000.label``), or, for a ``.bin`` in ``velodyne/``, in the
    sequence's ``labels/`` beside it."""
    p = Path(bin_path)
    for cand in (p.with_suffix(".label"), _layout_label(p)):
        if cand is not None and cand.is_file():
            return cand
    return None


def input_sidecars(path, fmt: str | None = None) -> list:
    """The files :func:`slr_ray.io.read_cloud` reads beside ``path`` read as ``fmt``
    (default: its extension; ``--input-format bin`` reads a ``.label`` beside any name):
    a ``.bin``'s labels."""
    if (fmt or Path(path).suffix).lower().lstrip(".") == "bin":
        lab = label_path(path)
        return [lab] if lab is not None else []
    return []


# --- temporaries ---------------------------------------------------------------------------------------------

_HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:40] or "host"
_PART = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)@(?P<host>[A-Za-z0-9_-]+)\.[^.]+\.part")


def part_prefix(path) -> str:
    """The start of a temporary's name for ``path``: ``.NAME.PID@HOST.``."""
    return f".{Path(path).name}.{os.getpid()}@{_HOST}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_parts(directory, names=None, *, locked: bool = False) -> list:
    """Remove temporaries left in ``directory`` by writers that died (kill -9,
    power loss): those of this host whose process is gone. With ``locked``
    (the caller holds the directory's lock, so no other run writes there),
    also those of an older slr_ray without host and process in the name.
    ``names``: only temporaries of these file names. Returns the paths removed."""
    d = Path(directory)
    if not d.is_dir():
        return []
    wanted = None if names is None else {Path(n).name for n in names}
    removed = []
    for p in d.iterdir():
        if not (p.name.startswith(".") and ".part" in p.name) or not p.is_file():
            continue
        m = _PART.match(p.name)
        if m is not None:
            stale = m["host"] == _HOST and not _alive(int(m["pid"]))
            name = m["name"]
        else:  # .NAME.RANDOM.partEXT (slr_ray before 0.2)
            stale = locked
            name = p.name[1:].rsplit(".part", 1)[0].rsplit(".", 1)[0]
        if stale and (wanted is None or name in wanted):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def link_new(src, dst) -> None:
    """Rename ``src`` to ``dst`` only if ``dst`` does not exist, atomically: a
    hard link (which the kernel refuses over any existing name, a dangling
    link included: :class:`FileExistsError`), then ``src`` removed. On a file
    system without hard links, a check and a rename (a narrow race)."""
    try:
        os.link(src, dst)
    except FileExistsError:
        raise FileExistsError(errno.EEXIST, "File exists", str(dst)) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.ENOSYS):
            raise
        if os.path.lexists(dst):
            raise FileExistsError(errno.EEXIST, "File exists", str(dst)) from None
        os.rename(src, dst)
        return
    os.unlink(src)


# --- identity ------------------------------------------------------------------------------------------------

def content_digest(path, block: int = 1 << 22) -> str:
    """BLAKE2b (128 bit) of the whole file, as hex: an input edited in place
    (same size, even the same mtime) has another digest. Reads the file once
    (about 1 GB/s a core; see docs/guarantees.md for the measured cost)."""
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


# --- the plan ------------------------------------------------------------------------------------------------

def _check_writable(directory: Path, named: str) -> None:
    """Refuse, before any work, an output in ``directory`` (or a directory to be
    created there: its nearest existing parent) that this process may not write:
    a read-only directory or file system, a directory of another user. A path
    through a regular file (``file/x``) is refused too."""
    d = directory
    while not d.exists():
        if d.is_symlink():  # a dangling link where a directory should be
            raise OutputError(f"{named}: {d} is a link to nothing")
        d = d.parent
    if not d.is_dir():
        raise OutputError(f"{named}: {d} is not a directory")
    effective = os.access in os.supports_effective_ids
    if not os.access(d, os.W_OK | os.X_OK, effective_ids=effective):
        raise OutputError(f"cannot write {named}: no permission to write in {d}"
                          f"{' (a read-only file system)' if _read_only_fs(d) else ''}")


def _read_only_fs(d: Path) -> bool:
    try:
        return bool(os.statvfs(d).f_flag & os.ST_RDONLY)
    except OSError:
        return False


class _Lock:
    """An advisory lock on ``directory/.slr_ray.lock`` (non-blocking): exclusive
    for a command that owns the directory (created if missing, removed at
    release), or ``shared`` for one that writes a single file there: taken only
    where the lock file exists (a directory command's), so that such a file is
    never written into a directory another run holds, and several single-file
    commands may write into one directory at once."""

    def __init__(self, directory: Path, shared: bool = False):
        self.path = directory / LOCK_NAME
        self.shared = shared
        self.fd = None

    def acquire(self) -> None:
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_RDONLY if self.shared else os.O_RDWR | os.O_CREAT, 0o666)
            except FileNotFoundError:
                if self.shared:
                    return  # no directory command writes there
                raise
            except PermissionError:
                if self.shared:
                    return  # another user's lock file: the directory's permissions decide
                raise
            try:
                fcntl.flock(fd, (fcntl.LOCK_SH if self.shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
            except OSError as exc:
                holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
                m = re.fullmatch(r"pid (\d+) on (\S+)", holder)
                if m is not None and m[2] == _HOST and not _alive(int(m[1])):
                    holder = ""  # a killed run's: the lock is held by a single-file command (shared)
                os.close(fd)
                if exc.errno in (errno.EAGAIN, errno.EACCES):
                    raise OutputError(f"{self.path.parent} is in use by another slr-ray run"
                                      f"{f' ({holder})' if holder else ''}: wait for it, "
                                      "or write elsewhere") from None
                raise
            # the file may have been removed by the run that held it, between our open and flock
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                if not self.shared:
                    os.ftruncate(fd, 0)
                    os.pwrite(fd, f"pid {os.getpid()} on {_HOST}".encode(), 0)
                self.fd = fd
                return
            os.close(fd)
        raise OutputError(f"cannot lock {self.path.parent}: its lock file keeps changing")

    def release(self) -> None:
        if self.fd is not None:
            if not self.shared:
                try:
                    os.unlink(self.path)
                except FileNotFoundError:
                    pass
            os.close(self.fd)
            self.fd = None


@contextmanager
def hold_directory(directory):
    """Lock ``directory`` (which exists) as :class:`OutputPlan` locks an output directory, for
    the ``with`` block: for a command that writes into subdirectories of its own (``sequence
    convert``'s ``velodyne/``, ``labels/``), so that a single file written there by another
    command meanwhile is refused (its shared lock), not replaced."""
    lock = _Lock(resolve(directory))
    lock.acquire()
    try:
        yield
    finally:
        lock.release()


def _refuse_directory_syntax(path, what) -> None:
    """Refuse a file named as a directory (``-o ts.npz/``: ``Path`` drops the
    slash, and a file ``ts.npz`` was written; the system refuses ``ts.npz/``
    as a file, so do we)."""
    text = os.fspath(path)
    if isinstance(text, str) and text.endswith(("/", os.sep, "/.")) and not os.path.isdir(text):
        raise OutputError(f"{text}: a path ending in '/' names a directory, and this {what} is a file: "
                          "drop the '/'")


class OutputPlan:
    """What one command reads and writes, checked before any work.

    Parameters
    ----------
    force : bool
        Existing output files may be replaced (never an input).

    Build it with :meth:`read`, :meth:`write` and :meth:`directory`, then
    ``with plan:`` (or :meth:`check` alone, for a plan without directories).
    Entering checks everything (:class:`~slr_ray.errors.OutputError` naming
    the path), creates and locks the output directories and removes stale
    temporaries; leaving releases the locks, and on an error also removes
    the directories the plan created if nothing else was left in them.

    Examples
    --------
    >>> plan = OutputPlan(force=False)
    >>> plan.read("in.bin")                       # doctest: +SKIP
    >>> out = plan.write("out.bin")               # doctest: +SKIP  (and out.label)
    >>> with plan:                                # doctest: +SKIP
    ...     write_cloud(out, cloud)
    """

    def __init__(self, force: bool = False):
        self.force = bool(force)
        self.inputs: dict = {}      # resolved -> as named
        self.outputs: dict = {}     # resolved -> as named
        self.resumed: dict = {}     # outputs a resumed run may replace without force
        self.directories: dict = {}
        self.checks: list = []      # (callable, path): an output's own check, e.g. its format
        self._locks: list = []
        self._created: list = []

    # -- building --
    def read(self, path, sidecars: bool = True, fmt: str | None = None):
        """An input (and, with ``sidecars``, what the reader of format ``fmt``, default
        the extension's, reads beside it). None is skipped."""
        if path is None:
            return None
        _refuse_directory_syntax(path, "input")
        self.inputs.setdefault(resolve(path), str(path))
        if sidecars:
            for s in input_sidecars(path, fmt):
                self.inputs.setdefault(resolve(s), str(s))
        return Path(path)

    def write(self, path, sidecars: bool = True, fmt: str | None = None, resumed: bool = False, check=None):
        """An output file (and, with ``sidecars``, what the writer of format ``fmt``,
        default the extension's, writes beside it). ``resumed``: a file the command
        itself may find from an earlier run and replace (augment's scans), exempt
        from the ``force`` check, never from the others. ``check``: a callable run
        on ``path`` with the plan's checks (it raises if the file cannot be written
        as named, e.g. an unknown format). Returns the path to write: through a
        link, the file it points to. None is skipped."""
        if path is None:
            return None
        _refuse_directory_syntax(path, "output")
        if check is not None:
            self.checks.append((check, path))
        for p in [Path(path)] + (output_sidecars(path, fmt) if sidecars else []):
            r = resolve(p)
            if r in self.outputs or r in self.resumed:
                raise OutputError(f"{p} is named twice among this command's outputs "
                                  f"({self.outputs.get(r) or self.resumed.get(r)} is the same file)")
            (self.resumed if resumed else self.outputs)[r] = str(p)
        return resolve(path)

    def directory(self, path) -> Path:
        """An output directory: created if missing and locked while the plan is entered."""
        r = resolve(path)
        self.directories.setdefault(r, str(path))
        return r

    # -- checking --
    def check(self) -> "OutputPlan":
        """Every check that needs no lock; raises OutputError; returns self."""
        inodes = {}
        for r, named in self.inputs.items():
            try:
                st = os.stat(r)
                inodes[(st.st_dev, st.st_ino)] = named
            except OSError:
                pass  # a missing input is the reader's error
        for r, named in self.directories.items():
            if r in self.inputs:
                raise OutputError(f"{named} is an input of this command")
            if r.exists() and not r.is_dir():
                raise OutputError(f"{named} exists and is not a directory")
            _check_writable(r, named)
        for r, named in [*self.outputs.items(), *self.resumed.items()]:
            resumed = r in self.resumed
            if r in self.inputs:
                raise OutputError(f"{named} is an input of this command ({self.inputs[r]}): refusing to write "
                                  "over it, with --force too")
            try:
                st = os.stat(r)
            except FileNotFoundError:
                st = None
            if st is not None:
                if not stat.S_ISREG(st.st_mode):
                    kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
                    raise OutputError(f"{named} is {kind}: refusing to write it")
                if (st.st_dev, st.st_ino) in inodes:
                    raise OutputError(f"{named} is the same file as the input {inodes[(st.st_dev, st.st_ino)]} "
                                      "(a hard link): refusing to write over it")
                if not self.force and not resumed:
                    raise OutputError(f"{named} exists (use --force to overwrite)")
            parent = r.parent
            planned = any(parent == d or d in parent.parents for d in self.directories)
            if not parent.is_dir() and not planned:
                raise OutputError(f"no directory {parent} for {named}")
            if not planned:
                _check_writable(parent, named)
        for check, path in self.checks:  # after the collisions: an input named as an output is said first
            check(path)
        return self

    # -- entering --
    def __enter__(self) -> "OutputPlan":
        self.check()
        try:
            for r in sorted(self.directories):
                missing = [p for p in [r, *r.parents] if not p.exists()]
                r.mkdir(parents=True, exist_ok=True)
                self._created += sorted(missing, key=lambda p: len(p.parts), reverse=True)
                lock = _Lock(r)
                lock.acquire()
                self._locks.append(lock)
                clean_stale_parts(r, locked=True)
            files = [*self.outputs, *self.resumed]
            for parent in sorted({r.parent for r in files} - set(self.directories)):
                if parent.is_dir():  # a directory another run holds (augment's) is not written into
                    lock = _Lock(parent, shared=True)
                    lock.acquire()
                    self._locks.append(lock)
                clean_stale_parts(parent, [r.name for r in files if r.parent == parent])
            self.check()  # again under the lock: another run may have written meanwhile
        except BaseException:
            self.__exit__(OutputError, None, None)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        for lock in reversed(self._locks):
            lock.release()
        self._locks.clear()
        if exc_type is not None:
            for d in self._created:  # deepest first
                try:
                    d.rmdir()
                except OSError:
                    pass  # not empty (or gone): what a run wrote there stays
        self._created.clear()
        return False
