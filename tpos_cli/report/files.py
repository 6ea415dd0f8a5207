"""Writing deliverables: whole files or nothing, readable by colleagues, no temporaries left behind.

Each output is written to a hidden sibling `.NAME.PID-RANDOM.tmp` created with mode 0666 less the
process umask (what `open()` gives any new file, so 0644 under umask 022; `tempfile.mkstemp` would
force 0600), then renamed over NAME. A Python-level interruption (Ctrl-C, SIGTERM through
`terminate_as_interrupt`, an error) removes the temporary; one left by a killed process is removed
by the next write into that directory once its PID is gone, as are the `.NAME.*.tmp` files of
earlier tpos versions (which carried no PID).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import signal
import stat
from collections.abc import Callable, Iterable
from pathlib import Path

from tpos_cli.errors import InvalidInputError, TposError

_TMP = re.compile(r"^\.(?P<name>.+)\.(?:(?P<pid>\d+)-[0-9a-f]+|[A-Za-z0-9_]+)\.tmp$")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def remove_stale_temporaries(directory: Path, names: Iterable[str]) -> list[Path]:
    """Delete `.NAME.*.tmp` siblings of the given output names whose writer is gone; returns them."""
    names = set(names)
    removed = []
    for p in Path(directory).glob(".*.tmp"):
        m = _TMP.match(p.name)
        if not m or m["name"] not in names:
            continue
        pid = m["pid"]
        if pid is not None and _pid_alive(int(pid)):
            continue  # a concurrent writer's file
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(p)
    return removed


def _temporary_name(path: Path) -> Path:
    return path.parent / f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp"


def _create(tmp: Path) -> None:
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for open()
    os.close(fd)


def check_replaceable(path: Path) -> None:
    """InvalidInputError (exit 2) unless `path` is absent, a regular file, or a link that is dangling or
    names a regular file: the output is written beside `path` and renamed over it, which would put a
    regular file in place of a device, FIFO, socket or directory, or of a link to one (as root,
    `/dev/stdout` itself, a link to the terminal or pipe). A link to a regular file is replaced, its
    target left alone."""
    path = Path(path)
    if not os.path.lexists(path):
        return
    mode = path.lstat().st_mode
    if stat.S_ISLNK(mode):
        try:
            mode = path.stat().st_mode
        except OSError:  # dangling or looping: nothing but the link is there to replace
            return
        what = "a link to a device, FIFO, socket or directory"
    else:
        what = "a device, FIFO, socket or directory"
    if not stat.S_ISREG(mode):
        raise InvalidInputError(f"{path}: exists and is not a regular file ({what}); outputs are written as whole "
                                "files: choose another output name")


@contextlib.contextmanager
def staged(paths: Iterable[Path]):
    """Temporaries for several outputs, all renamed into place only when the block succeeds.

    Yields {final path: temporary path}; the caller writes each temporary. On any exception (or
    KeyboardInterrupt) every temporary is removed and no final file is touched. A target that is
    not replaceable (`check_replaceable`) is refused (exit 2) before anything is written.
    """
    paths = [Path(p) for p in paths]
    for p in paths:
        check_replaceable(p)
    for d in {p.parent for p in paths}:
        remove_stale_temporaries(d, [p.name for p in paths if p.parent == d])
    tmps: dict[Path, Path] = {}
    try:
        for p in paths:  # named before it exists: an interruption right after its creation still removes it
            tmps[p] = _temporary_name(p)
            try:
                _create(tmps[p])
            except OSError as exc:
                raise _cannot_write(p, exc) from None
        try:
            yield tmps
        except OSError as exc:
            if exc.errno not in _FULL_OR_READ_ONLY:
                raise
            named = [p for p, t in tmps.items() if exc.filename is not None and str(t) == str(exc.filename)]
            raise _cannot_write(named[0] if named else paths[0] if len(paths) == 1 else paths[0].parent, exc) from None
        for p, tmp in tmps.items():
            try:
                os.replace(tmp, p)
            except OSError as exc:
                raise _cannot_write(p, exc) from None
    finally:
        for tmp in tmps.values():
            with contextlib.suppress(OSError):  # absent, or never created (a read-only directory)
                tmp.unlink()


# Errors of the output file system, not of the data: a one-line message, not an internal error.
_FULL_OR_READ_ONLY = {errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _cannot_write(path: Path, exc: OSError) -> TposError:
    """`OSError` of writing `path` (read-only or full file system; at creation also no permission) as a plain error (exit 1)."""
    return TposError(f"cannot write {path}: {exc.strerror or exc}")


def write_atomic(path: Path, write: Callable[[Path], object]) -> None:
    """`write(tmp_path)` then rename over `path` (see module docstring)."""
    with staged([path]) as tmps:
        write(tmps[Path(path)])


@contextlib.contextmanager
def terminate_as_interrupt():
    """Turn SIGTERM into KeyboardInterrupt inside the block, so `kill PID` cleans up like Ctrl-C.

    Only in the main thread (signal handlers can only be set there); elsewhere a no-op.
    """
    try:
        previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt
