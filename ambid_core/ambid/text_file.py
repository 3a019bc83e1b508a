"""A user's text file (a rig file, a model file) read whole, or one line saying why not.

The one place that turns the ways a text file can be unusable (missing, a
folder, binary data) into a ``ValueError`` whose message names the file and
ends with the caller's fix; what the text must hold is the caller's to check.
"""

from __future__ import annotations

import os

__all__ = ["read_text"]


def read_text(path: str | os.PathLike, what: str = "", fix: str = "", binary: str = "is not text (binary data)") -> str:
    """The UTF-8 text of ``path``.

    Parameters
    ----------
    path
        the file.
    what
        what the file is, for messages ("rig file"); "" names the path alone.
    fix
        the fix a message ends with, after "; " ("" for none).
    binary
        what the message says of a file that is not UTF-8 text.

    Raises
    ------
    ValueError
        "<what> <path> does not exist", "... is a folder" or "... <binary>",
        then "; <fix>".
    """
    name = f"{what} {os.fspath(path)}" if what else os.fspath(path)
    tail = f"; {fix}" if fix else ""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        raise ValueError(f"{name} does not exist{tail}") from None
    except IsADirectoryError:
        raise ValueError(f"{name} is a folder{tail}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{name} {binary}{tail}") from None
