"""Opening a file a user named, without trusting it: regular files only, a size limit, no blocking.

`open(path).read()` on `/dev/zero`, a FIFO or a multi-gigabyte file never returns (or
exhausts memory), and `open()` itself blocks on a FIFO until another process opens its other
end. Every file is therefore opened with O_NONBLOCK and checked with fstat before anything is
read or written. Every reader of user files (config, includes, tap files, G-code files, the
virtual bed's CSV) goes through `read_limited`, every appending writer (logs) through
`open_append`; each turns `FileRefused` and `OSError` into its own error that names the file.

Files tapcell writes whole (the config at SAVE_CONFIG, the Kalico plug-in) go through
`replace_atomically`: never torn, and no temp file left behind even by SIGKILL.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from collections.abc import Callable
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


def _open_regular(path: str | os.PathLike, flags: int, keep_nonblocking: bool = False) -> tuple[int, os.stat_result]:
    """A descriptor for `path`, opened without blocking, and its status (a reader takes the size from it:
    one call fewer); FileRefused (closing it) if it is not a regular file. `keep_nonblocking`: leave
    O_NONBLOCK set (reads of a regular file ignore it; a reader spares two calls)."""
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
    if not keep_nonblocking:
        # A regular file never blocks; clear the flag so that the file behaves as opened plainly.
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return fd, info


def why_missing(path: str | os.PathLike) -> str:
    """Why `path` names no file: 'does not exist', or a symbolic link that leads nowhere."""
    if os.path.lexists(path):
        return "is a symbolic link that leads nowhere (a loop, or its target is missing)"
    return "does not exist"


def read_limited(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The file's bytes; FileRefused for a device, FIFO, socket or directory or beyond `max_bytes`.

    OSError (missing file, no permission) passes through.
    """
    # Plain os.read on the descriptor: a file object around it costs more than reading a tap file.
    fd, info = _open_regular(path, os.O_RDONLY, keep_nonblocking=True)
    try:
        size = info.st_size
        # Sized by the file, not the limit: read(n) sets n bytes aside first, and most files are small.
        wanted = min(size, max_bytes) + 1
        parts = [os.read(fd, wanted)]
        total = len(parts[0])
        # A short read of a regular file is its end; a full one means it is still growing: read
        # on (a megabyte at a time), the limit stops it.
        while total == wanted and total <= max_bytes:
            wanted = total + min(max_bytes + 1 - total, 1 << 20)
            parts.append(os.read(fd, wanted - total))
            total += len(parts[-1])
    finally:
        os.close(fd)
    data = parts[0] if len(parts) == 1 else b"".join(parts)
    if len(data) > max_bytes:
        raise FileRefused(f"is larger than {max_bytes:,} bytes")
    return data


def open_append(path: str | os.PathLike) -> TextIO:
    """`path` opened to append UTF-8 text (created 0644 if missing); FileRefused unless it is a regular file.

    OSError (missing folder, no permission) passes through.
    """
    fd, _ = _open_regular(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
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


def replace_atomically(path: str, data: bytes, *, mode: int | None = None,
                       owner: tuple[int, int] | None = None) -> None:
    """Put `data` at `path` by a rename, so readers see the old file or the new one, never part.

    The temp file is made without a name (O_TMPFILE), written, given `mode` and `owner`
    (uid, gid) and fsynced, then named `.<name>.<8 characters>.tmp` and renamed over `path`
    at once: a process killed while writing leaves nothing, and one killed in the microseconds
    between the two leaves a name `is_temp_of(name, path)` recognises. Where the system has no
    O_TMPFILE a named temp file is written instead. Without `mode` it is 0600 (mkstemp's).
    On an error the temp file is removed and `path` is untouched; OSError passes through.
    """
    temp_path = None
    try:
        temp_path = _write_unnamed(path, data, mode, owner) or _write_named(path, data, mode, owner)
        os.replace(temp_path, path)
    except BaseException:
        if temp_path is not None:
            try:
                os.unlink(temp_path)
            except FileNotFoundError:
                pass
        raise


def is_temp_of(name: str, path: str) -> bool:
    """Whether `name` (in the folder of `path`) is a temp file replace_atomically makes for `path`
    or its `.bak`: `.printer.cfg.1a2b3c4d.tmp`, not another file's (`printer.cfg.old`'s)."""
    prefix = f".{os.path.basename(path)}."
    if not (name.startswith(prefix) and name.endswith(".tmp")):
        return False
    middle = name[len(prefix):-len(".tmp")].removeprefix("bak.")
    return len(middle) == 8 and all(char.isascii() and (char.isalnum() or char == "_") for char in middle)


def _finish_temp(fd: int, data: bytes, mode: int | None, owner: tuple[int, int] | None) -> None:
    """Write, give mode and owner, and make durable."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
    if mode is not None:
        os.fchmod(fd, mode)
    if owner is not None:
        created = os.fstat(fd)
        if owner != (created.st_uid, created.st_gid):
            os.fchown(fd, *owner)
    os.fsync(fd)


def _write_unnamed(path: str, data: bytes, mode: int | None, owner: tuple[int, int] | None) -> str | None:
    """The complete temp file, named; None where the system cannot make unnamed files."""
    try:
        fd = os.open(os.path.dirname(path) or ".", os.O_TMPFILE | os.O_WRONLY | os.O_CLOEXEC, 0o600)
    except (AttributeError, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno not in (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL):
            raise
        return None  # no O_TMPFILE here (another OS, an old kernel, a file system without it)
    import secrets  # here: readers (`tapcell analyze` above all) start without it

    try:
        _finish_temp(fd, data, mode, owner)
        while True:
            name = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{secrets.token_hex(4)}.tmp")
            try:
                os.link(f"/proc/self/fd/{fd}", name, follow_symlinks=True)
                return name
            except FileExistsError:
                continue
            except OSError as exc:
                if exc.errno in (errno.ENOENT, errno.EPERM, errno.EXDEV):
                    return None  # no /proc to name it through: write a named one
                raise
    finally:
        os.close(fd)


def _write_named(path: str, data: bytes, mode: int | None, owner: tuple[int, int] | None) -> str:
    import tempfile  # here: readers (`tapcell analyze` above all) start without it

    fd, temp_path = tempfile.mkstemp(dir=os.path.dirname(path) or ".", prefix=f".{os.path.basename(path)}.",
                                     suffix=".tmp")
    try:
        _finish_temp(fd, data, mode, owner)
    except BaseException:
        os.close(fd)
        os.unlink(temp_path)
        raise
    os.close(fd)
    return temp_path


def remove_stale_temps(path: str) -> None:
    """Remove temp files replace_atomically left for `path` when its process was killed.

    Call it only while holding a lock every writer of `path` holds while writing: then any
    temp file found belongs to a writer that is no longer running."""
    directory = os.path.dirname(path) or "."
    try:
        names = os.listdir(directory)
    except OSError:
        return
    for name in names:
        if is_temp_of(name, path):
            try:
                os.unlink(os.path.join(directory, name))
            except OSError:
                pass  # removed meanwhile, or not ours to remove: the write goes on


def extract_archive(archive: str | os.PathLike, target: str | os.PathLike,
                    keep: Callable[[str], bool] | None = None) -> None:
    """Unpack a tar archive (any compression tarfile reads) into `target`: its members whose name `keep`
    accepts (all without it). A member that is not a regular file or a folder (a link, a device), or
    that would land outside `target`, is a tarfile.TarError before anything is written: the rules of
    tarfile's "data" filter, which a Python before 3.11.4 does not have (Debian 12's is 3.11.2)."""
    import tarfile  # here: only the benchmarks unpack archives, and every command's start-up would pay for it

    root = os.path.realpath(target)
    with tarfile.open(archive) as packed:
        members = [member for member in packed.getmembers() if keep is None or keep(member.name)]
        for member in members:
            landing = os.path.realpath(os.path.join(root, member.name))
            if not (member.isfile() or member.isdir()) or os.path.commonpath([root, landing]) != root:
                raise tarfile.TarError(f"{member.name!r} is not a file or folder inside the archive's own tree")
        packed.extractall(root, members=members, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
