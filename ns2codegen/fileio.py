"""Atomic file output: a file is either the old one or the complete new one."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from .errors import Ns2Error


def file_mode() -> int:
    """Mode of a newly created file under the current umask (mkstemp makes 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


class OutputError(Ns2Error, OSError):
    """An output location cannot be written."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
    except OSError as e:
        raise OutputError(f"cannot write to {path.parent}: {e.strerror or e}") from e
    try:
        os.chmod(tmp, file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_files(folder: Path, files: dict[str, str]) -> None:
    """Write several text files so that none is replaced unless all could be staged.

    All contents are first written to temporary files in ``folder``; only when every
    one succeeded are they renamed into place (each rename is atomic)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create output folder {folder}: {e.strerror or e}") from e
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {folder} is not writable")
    staged: list[tuple[str, Path]] = []
    try:
        for name, text in files.items():
            fd, tmp = tempfile.mkstemp(dir=folder, prefix="." + name, suffix=".tmp")
            staged.append((tmp, folder / name))
            os.chmod(tmp, file_mode())
            with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
    except OSError as e:
        for tmp, _ in staged:
            Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"cannot write to {folder}: {e.strerror or e}") from e
    for tmp, dst in staged:
        os.replace(tmp, dst)
