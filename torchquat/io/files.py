"""Writing files safely: refuse an output that cannot be written, and replace it atomically."""

import json
import os
import tempfile
from contextlib import contextmanager, suppress
from typing import BinaryIO, Iterator, Optional, Union

from .poses import PoseFileError

__all__ = ["output_folder_problem", "atomic_output", "write_json"]

PathLike = Union[str, os.PathLike]


def output_folder_problem(path: PathLike) -> Optional[str]:
    """Why a file cannot be written at ``path``, or ``None``.

    Commands ask before a long run rather than fail after it.

    Args:
        path: the file to be written.

    Returns:
        ``"<path>: <reason>"`` (its folder is missing or read-only, or ``path`` is a folder), or None.
    """
    reason = _output_reason(path)
    return None if reason is None else f"{os.fspath(path)}: {reason}"


def _output_reason(path: PathLike) -> Optional[str]:
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        return f"no such folder {directory}"
    if os.path.isdir(path):
        return "is a folder"
    if not os.access(directory, os.W_OK):
        return f"the folder {directory} is not writable"
    return None


@contextmanager
def atomic_output(path: PathLike) -> Iterator[BinaryIO]:
    """Write to a temporary file beside ``path`` and rename it into place only on success.

    On any exception the temporary file is removed and ``path`` is left as it was.

    Args:
        path: the file to write.

    Returns:
        A context manager giving a binary stream.
    """
    path = os.fspath(path)
    reason = _output_reason(path)  # (named now: else the temporary file's name, or a failed rename at the end)
    if reason is not None:
        raise PoseFileError(path, reason)
    directory = os.path.dirname(os.path.abspath(path))
    fd, temporary = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb", buffering=1 << 20) as stream:
            yield stream
        os.chmod(temporary, _mode_for(path))
        try:
            os.replace(temporary, path)
        except OSError as exc:  # (its message names the temporary file, which is about to go)
            raise PoseFileError(path, f"could not be replaced: {exc.strerror or exc}") from exc
    except BaseException:
        with suppress(OSError):
            os.unlink(temporary)
        raise


def _mode_for(path: str) -> int:
    """The permissions the output gets: the replaced file's, else what ``open`` would give."""
    try:
        return os.stat(path).st_mode & 0o777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def write_json(path: PathLike, data) -> None:
    """Write ``data`` as indented JSON through :func:`atomic_output`.

    A failed write (a full disk, a file that cannot be replaced) leaves an existing file as it was.
    """
    with atomic_output(path) as stream:
        stream.write(json.dumps(data, indent=1, default=str).encode("utf-8") + b"\n")
