"""Opening a file a user named, without trusting it: regular files only, a size limit, no blocking.

`open(path).read()` on `/dev/zero`, a FIFO or a multi-gigabyte file never returns (or
exhausts memory), and `open()` itself blocks on a FIFO until another process opens its other
end. Every file is therefore opened with O_NONBLOCK and checked with fstat before anything is
read or written. Every reader of user files (config, includes, tap files, G-code files, the
virtual bed's CSV) goes through `read_limited`, every appending writer (logs) through
`open_append`; each turns `FileRefused` and `OSError` into its own error that names the file.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from typing import TextIO


class FileRefused(Exception):
    """The file is not something to read whole (the message is the problem, e.g. 'is a FIFO (named pipe)')."""


def _kind(mode: int) -> str:
    """What a non-regular file is, in the words of the message ('a directory', 'a FIFO (named pipe)')."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a regular file"  # (a door or a whiteout: no Linux file system has one)


def _open_regular(path: str | os.PathLike, flags: int) -> int:
    """A descriptor for `path`, opened without blocking; FileRefused (closing it) if it is not a regular file."""
    try:
        fd = os.open(path, flags | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0), 0o666)
    except IsADirectoryError:
        raise FileRefused("is a directory") from None
    except OSError as problem:
        # ENXIO: a socket, or a FIFO opened for writing that nobody reads; name what is there.
        if problem.errno in (errno.ENXIO, errno.EOPNOTSUPP):
            mode = os.stat(path).st_mode
            if not stat.S_ISREG(mode):
                raise FileRefused(f"is {_kind(mode)}") from None
        raise
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise FileRefused(f"is {_kind(info.st_mode)}")
    # A regular file never blocks; clear the flag so that the file behaves as opened plainly.
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return fd


def read_limited(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The file's bytes; FileRefused for a device, FIFO, socket or directory or beyond `max_bytes`.

    OSError (missing file, no permission) passes through.
    """
    with os.fdopen(_open_regular(path, os.O_RDONLY), "rb") as handle:
        info = os.fstat(handle.fileno())
        # Sized by the file, not the limit: read(n) sets n bytes aside first, and most files are small.
        data = handle.read(min(info.st_size, max_bytes) + 1)
        if len(data) > info.st_size:  # still growing: read on, the limit stops it
            data += handle.read(max_bytes + 1 - len(data))
    if len(data) > max_bytes:
        raise FileRefused(f"is larger than {max_bytes:,} bytes")
    return data


def open_append(path: str | os.PathLike) -> TextIO:
    """`path` opened to append UTF-8 text (created 0644 if missing); FileRefused unless it is a regular file.

    OSError (missing folder, no permission) passes through.
    """
    fd = _open_regular(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    return os.fdopen(fd, "a", encoding="utf-8")


def check_appendable(path: str | os.PathLike) -> str | None:
    """Why `path` cannot take appended lines ('is a directory'), or None."""
    try:
        open_append(path).close()
    except FileRefused as problem:
        return str(problem)
    except OSError as problem:
        return f"cannot be written ({problem.strerror or problem})"
    return None
