"""A disk that fills up, for the recorder: patch it in as ``recorder.writer.open``."""

from __future__ import annotations

import errno
import io
import os
from pathlib import Path
from typing import IO, Any


class SmallDisk:
    """A disk with ``free`` bytes left: a write that does not fit fails as write(2) does on a full disk."""

    def __init__(self, free: int) -> None:
        self.free = free

    def open(self, path: Path, mode: str) -> IO[bytes]:
        return io.BufferedWriter(_SmallDiskFile(path, mode, self))


class _SmallDiskFile(io.FileIO):
    def __init__(self, path: Path, mode: str, disk: SmallDisk) -> None:
        super().__init__(path, mode)
        self._disk = disk

    def write(self, data: Any) -> int:
        size = len(memoryview(data))
        if size > self._disk.free:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._disk.free -= size
        return super().write(data)
