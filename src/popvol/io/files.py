"""Writing files so that a failed or interrupted write never leaves a truncated file behind."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def write_atomically(path, write) -> None:
    """Call ``write(tmp)`` with a temporary file's path beside ``path`` (same folder and suffix),
    then rename it over ``path`` in one step: an error, Ctrl-C or a full disk leaves ``path``
    as it was, and a reader never sees a partial file. The file gets the permissions the
    umask gives new files."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text_atomically(path, text: str) -> None:
    """:func:`write_atomically` for a text file (UTF-8)."""
    write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def check_writable_folder(folder, what: str) -> None:
    """A one-line PopvolError unless a file can be created in ``folder`` (outputs are written
    through a temporary file beside them); ``what`` starts the message (an option and its value)."""
    from ..errors import PopvolError
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise PopvolError(f"{what}: cannot write in folder {folder} ({e.strerror or e})") from None
