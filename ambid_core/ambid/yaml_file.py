"""A YAML file a user writes (a rig, a MAP.yaml, a controller), read the way people write numbers.

PyYAML resolves plain scalars by YAML 1.1, whose float needs a dot and a
signed exponent: ``2e-05``, ``1e3`` and ``1E-3`` stay strings there, and a
file that says ``scale: 2e-05`` is refused as "not a number". Here every
scalar that reads as a number in YAML 1.2 (and in Python, C and MATLAB) is
one: ``2e-05``, ``1e3``, ``.5``, ``-1E-3``, ``+3``, ``.inf``; whole numbers
stay ``int``. Everything else resolves as PyYAML does.

Every reader of a user's YAML (:mod:`ambid.plant.rig`, :mod:`ambid.records.mapping`,
:mod:`ambid.array_file`) goes through :func:`read_yaml` or :func:`load_yaml`, so
one file format has one meaning; a file that cannot be used is a one-line
``ValueError`` naming the file, where it broke and the caller's fix.
"""

from __future__ import annotations

import os
import re
from typing import Any

import yaml

from ambid.text_file import read_text, refusal

__all__ = ["NumberLoader", "load_yaml", "read_yaml"]

_BASE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class NumberLoader(_BASE):  # type: ignore[misc, valid-type]
    """PyYAML's safe loader with YAML 1.2's float forms (exponent without a dot or sign, ``.5``)."""


# after PyYAML's own int resolver (registered first, so "12" stays an int): any decimal with an optional
# fraction and exponent, as YAML 1.2's core schema and float() read it
_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)?$"
                    r"|^[-+]?\.(?:inf|Inf|INF)$|^\.(?:nan|NaN|NAN)$")
NumberLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))


def load_yaml(text: str) -> Any:
    """The YAML ``text`` parsed with numbers as people write them (module docstring).

    Raises
    ------
    yaml.YAMLError
        the text is not YAML (the caller names the file; :func:`read_yaml` does).
    """
    return yaml.load(text, Loader=NumberLoader)  # noqa: S506 - a safe loader


def read_yaml(path: str | os.PathLike, what: str, fix: str, allow_empty: bool = True) -> Any:
    """The YAML content of a user's file, numbers as people write them.

    Parameters
    ----------
    path
        the file.
    what, fix
        what the file is and the fix a message ends with (:func:`ambid.text_file.refusal`).
    allow_empty
        False refuses a file of nothing but white space ("... is empty").

    Returns
    -------
    What the file holds (None for a file without a document, e.g. comments only).

    Raises
    ------
    ValueError
        one line: the file is missing, a folder, binary, empty (``allow_empty`` False) or not
        YAML (with the line), then "; <fix>".
    """
    text = read_text(path, what, fix, binary="is not YAML text (binary data)")
    if not allow_empty and not text.strip():
        raise refusal(path, what, "is empty", fix)
    try:
        return load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise refusal(path, what, f"is not YAML text{at}", fix) from None
