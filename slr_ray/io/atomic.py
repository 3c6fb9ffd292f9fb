"""Atomic writes: a file appears under its name complete, or not at all."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError
from .outputs import part_prefix, resolve

__all__ = ["atomic_path"]


def _umask() -> int:
    """The process's umask, read without changing it where Linux allows."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)  # elsewhere: the classic read-and-restore
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success,
    remove it on failure, so no half-written file is ever left under ``path``.

    A ``path`` that is a symbolic link is written *through*: the file it
    points to is replaced and the link stays. A ``path`` that exists and is
    not a regular file (a directory, a device, a FIFO) is refused with
    :class:`~slr_ray.errors.OutputError`. The temporary is named
    ``.NAME.PID@HOST.RANDOM.partEXT``, so that the next run can tell one left
    by a killed process (:func:`slr_ray.io.outputs.clean_stale_parts`).

    The file gets the mode a plain ``open(path, "w")`` would give it (0666
    less the umask), not the 0600 of a temporary file: colleagues on shared
    storage can read what slr_ray writes when their umask lets them.
    """
    target = resolve(path)
    if target.exists() and not target.is_file():
        raise OutputError(f"{path} is not a regular file: refusing to write it")
    fd, tmp = tempfile.mkstemp(prefix=part_prefix(target), suffix=".part" + target.suffix, dir=target.parent)
    os.fchmod(fd, 0o666 & ~_umask())
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename in (None, tmp, str(tmp)):
            # a writer's 'File too large' or 'No space left on device' names no file, or our temporary;
            # numpy's tofile says '76468 requested and 1024 written', without an errno
            if exc.errno is not None:
                raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from exc
            raise OSError(f"cannot write {path}: {exc} (a full disk, or a file-size limit?)") from exc
        raise
