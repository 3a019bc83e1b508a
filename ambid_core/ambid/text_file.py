"""A user's text file (a rig file, a model file) read whole, or one line saying why not.

The one place that turns the ways a text file can be unusable (missing, a
folder, binary data) into a ``ValueError`` whose message names the file and
ends with the caller's fix; what the text must hold is the caller's to check.
"""

from __future__ import annotations

import os

__all__ = ["read_text", "refusal"]


def refusal(path: str | os.PathLike, what: str, problem: str, fix: str) -> ValueError:
    """The one-line ValueError about a user's file: ``"<what> <path> <problem>; <fix>"``.

    ``what`` "" names the path alone; ``fix`` "" ends the line after the problem.

    Examples
    --------
    >>> refusal("rig.yaml", "rig file", "is empty", "write the parameters in it")
    ValueError('rig file rig.yaml is empty; write the parameters in it')
    """
    name = f"{what} {os.fspath(path)}" if what else os.fspath(path)
    return ValueError(f"{name} {problem}" + (f"; {fix}" if fix else ""))


def read_text(path: str | os.PathLike, what: str = "", fix: str = "", binary: str = "is not text (binary data)") -> str:
    """The UTF-8 text of ``path``.

    Parameters
    ----------
    path
        the file.
    what, fix
        what the file is and the fix a message ends with (:func:`refusal`).
    binary
        what the message says of a file that is not UTF-8 text.

    Raises
    ------
    ValueError
        "<what> <path> does not exist", "... is a folder" or "... <binary>",
        then "; <fix>".
    """
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        raise refusal(path, what, "does not exist", fix) from None
    except IsADirectoryError:
        raise refusal(path, what, "is a folder", fix) from None
    except UnicodeDecodeError:
        raise refusal(path, what, binary, fix) from None
