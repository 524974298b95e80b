"""Reading a file a user named, without trusting it: regular files only, and a size limit.

`open(path).read()` on `/dev/zero`, a FIFO or a multi-gigabyte file never returns (or
exhausts memory). Every reader of user files (config, tap files, the virtual bed's CSV)
goes through `read_limited`, and turns `FileRefused` and `OSError` into its own error
that names the file.
"""

from __future__ import annotations

import os
import stat


class FileRefused(Exception):
    """The file is not something to read whole (the message is the problem, e.g. 'is not a regular file')."""


def read_limited(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The file's bytes; FileRefused for a device, FIFO or directory or beyond `max_bytes`.

    OSError (missing file, no permission) passes through.
    """
    with open(path, "rb") as handle:
        info = os.fstat(handle.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise FileRefused("is not a regular file")
        # Sized by the file, not the limit: read(n) sets n bytes aside first, and most files are small.
        data = handle.read(min(info.st_size, max_bytes) + 1)
        if len(data) > info.st_size:  # still growing: read on, the limit stops it
            data += handle.read(max_bytes + 1 - len(data))
    if len(data) > max_bytes:
        raise FileRefused(f"is larger than {max_bytes:,} bytes")
    return data
