"""Writing files so that a failed or interrupted write never leaves a truncated file behind."""
from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path


def write_atomically(path, write) -> None:
    """Call ``write(tmp)`` with a temporary file's path beside ``path`` (same folder and suffix),
    then rename it over ``path`` in one step: an error, Ctrl-C or a full disk leaves ``path``
    as it was, and a reader never sees a partial file. The file gets the permissions the
    umask gives new files."""
    write_atomically_together([(path, write)])


def write_atomically_together(items) -> None:
    """:func:`write_atomically` for several files that belong together (an image and its EXR):
    ``items`` is a list of (path, write). Every file is written to its temporary file first and
    only then are they renamed over their paths, so a write that fails (a full disk, an error,
    Ctrl-C) replaces none of them."""
    umask = os.umask(0)
    os.umask(umask)
    temps = []
    try:
        for path, write in items:
            path = Path(path)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
            os.close(fd)
            temps.append((Path(tmp), path))
            os.chmod(tmp, 0o666 & ~umask)
            write(Path(tmp))
        while temps:
            tmp, path = temps[0]
            os.replace(tmp, path)
            temps.pop(0)
    except BaseException:
        for tmp, _ in temps:
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


def why_missing(path) -> str:
    """Why ``path`` cannot be opened, in a message's words: "is a loop of symbolic links", "is a
    symbolic link to TARGET, which does not exist", "FOLDER is a file, not a folder" (a folder
    on its way is a file), else "not found"."""
    path = Path(path)
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "is a loop of symbolic links"
        if e.errno == errno.ENOTDIR:
            for parent in reversed(path.parents):
                if parent.exists() and not parent.is_dir():
                    return f"{parent} is a file, not a folder"
        if path.is_symlink():
            return f"is a symbolic link to {os.readlink(path)}, which does not exist"
    return "not found"


def folder_problem(folder) -> str:
    """Why ``folder`` cannot hold an output, in a message's words ("does not exist", "is a file,
    not a folder", ...: :func:`why_missing`), or "" where it is a folder."""
    folder = Path(folder)
    if folder.is_dir():
        return ""
    if folder.exists():
        return "is a file, not a folder"
    why = why_missing(folder)
    return "does not exist" if why == "not found" else why


def why_not_file(path) -> str:
    """Why ``path`` is not a file to read: "is not a file" where it exists (a folder, a device),
    else :func:`why_missing`."""
    return "is not a file" if Path(path).exists() else why_missing(path)


def file_name(value, what: str):
    """``value`` if it is a file or folder name (str or os.PathLike, not bytes); else one line
    naming ``what`` (the argument) and the type it got."""
    if isinstance(value, (str, os.PathLike)) and not isinstance(value, bytes):
        return value
    from ..errors import PopvolError
    raise PopvolError(f"{what} must be a file name (str or Path), not {type(value).__name__}")
