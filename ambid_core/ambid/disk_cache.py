"""Results that depend only on their inputs, computed once and kept on disk.

Used where a deterministic computation costs seconds every run and its
inputs repeat: the crest-factor optimisation of a multisine's phases (the
same design every ``ambid identify``). A result is stored as the float64
array it is (``.npy``), so a cached result equals a fresh one to the bit.

The key is a SHA-256 of everything the result depends on: the caller's
inputs, the source of the module that computes it (a change of the code is
a new key), and numpy's and scipy's versions and the machine type (their
arithmetic may differ in the last bits).

Where: ``$AMBID_CACHE_DIR`` (``launch_scripts/setup/setup.sh`` sets the
checkout's ``.cache``), else ``$XDG_CACHE_HOME/ambid``, else
``~/.cache/ambid``; ``AMBID_CACHE_DIR=off`` computes every time. A cache
that cannot be read or written is skipped, never an error.
"""

from __future__ import annotations

import hashlib
import os
import platform
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np


def cache_dir() -> Path | None:
    """The cache folder, or None when caching is off (``AMBID_CACHE_DIR=off``)."""
    env = os.environ.get("AMBID_CACHE_DIR")
    if env == "off":
        return None
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ambid"


def _versions() -> bytes:
    import scipy

    return f"numpy {np.__version__} scipy {scipy.__version__} {platform.machine()}".encode()


def cache_key(name: str, source_file: str | os.PathLike, parts: Iterable) -> str:
    """Hex SHA-256 of ``name``, the bytes of ``source_file``, the library versions and ``parts`` (arrays
    by dtype, shape and bytes; anything else by ``repr``)."""
    h = hashlib.sha256(name.encode())
    h.update(Path(source_file).read_bytes())
    h.update(_versions())
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(p).encode())
        h.update(b"\0")
    return h.hexdigest()


def cached_array(name: str, source_file: str | os.PathLike, parts: Iterable,
                 compute: Callable[[], np.ndarray]) -> np.ndarray:
    """``compute()``, or the array an earlier call with the same key stored (:func:`cache_key`).

    Parameters
    ----------
    name
        what is computed (a folder of the cache).
    source_file
        the module whose code computes it.
    parts
        every input the result depends on.
    compute
        computes the float64 array when it is not stored.
    """
    folder = cache_dir()
    if folder is None:
        return compute()
    path = folder / name / f"{cache_key(name, source_file, parts)}.npy"
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError):  # not there yet, or unreadable: computed
        pass
    result = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # written beside and renamed: a reader (another process) sees the whole file or none
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.save(f, result, allow_pickle=False)
        os.replace(tmp, path)
    except OSError:
        pass
    return result
