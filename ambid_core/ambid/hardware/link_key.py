"""The rig's link key: the secret that authenticates every datagram of protocol version 3.

A key file (``ambid keygen --out FILE`` writes one, mode 0600) holds one line of hex digits, the key (16 to 64
bytes; keygen writes 32), after comment lines starting with ``#``::

    # ambid link key (HMAC-SHA-256, bridge protocol version 3); secret: keep it mode 0600
    # fingerprint 3f2a9c0d51b7e466
    5c1f...(64 hex digits)

The bridge and the target of one rig read the same file. A key file that the group or others may read (or
write) is refused, as ssh refuses such a private key. The key itself is never printed, logged, published or
recorded: a :class:`LinkKey` shows its fingerprint only (the first 8 bytes of SHA-256 over
``b"ambid link key\\0"`` and the key, which the C target computes alike), and it cannot be pickled.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import stat

__all__ = ["KEY_BYTES", "MIN_KEY_BYTES", "MAX_KEY_BYTES", "KeyFileError", "LinkKey", "key_fingerprint",
           "read_key_file", "write_key_file"]

KEY_BYTES = 32       # what keygen writes: SHA-256's own size
MIN_KEY_BYTES = 16   # HMAC-SHA-256 keys shorter than this are too weak to accept
MAX_KEY_BYTES = 64   # one SHA-256 block: longer keys would be hashed first, which buys nothing
MAX_FILE_BYTES = 4096
FINGERPRINT_PREFIX = b"ambid link key\0"
KEYGEN_FIX = "write one with 'ambid keygen --out FILE' and give the bridge and the target the same file"


class KeyFileError(ValueError):
    """A key file that cannot be used; the message is one line naming the file, the problem and the fix."""


def key_fingerprint(secret: bytes) -> str:
    """16 hex digits that name a key without revealing it (SHA-256 of a fixed prefix and the key)."""
    return hashlib.sha256(FINGERPRINT_PREFIX + bytes(secret)).hexdigest()[:16]


class LinkKey:
    """A link key ready to tag datagrams; shows only its fingerprint.

    Args:
        secret: the key, MIN_KEY_BYTES to MAX_KEY_BYTES bytes.

    Examples:
        >>> k = LinkKey(bytes(range(32)))
        >>> k
        LinkKey(fingerprint=...)
        >>> len(k.tag(b"datagram")), len(k.mac(b"a", b"b"))
        (16, 32)
    """

    __slots__ = ("_mac", "fingerprint")

    def __init__(self, secret: bytes) -> None:
        secret = bytes(secret)
        if not MIN_KEY_BYTES <= len(secret) <= MAX_KEY_BYTES:
            raise ValueError(f"a link key has {MIN_KEY_BYTES} to {MAX_KEY_BYTES} bytes, this one {len(secret)}")
        self._mac = hmac.new(secret, digestmod=hashlib.sha256)  # the key's pads hashed once
        self.fingerprint = key_fingerprint(secret)

    def mac(self, *parts: bytes) -> bytes:
        """HMAC-SHA-256 (32 bytes) of the concatenated ``parts``."""
        m = self._mac.copy()
        for p in parts:
            m.update(p)
        return m.digest()

    def tag(self, data: bytes, n: int = 16) -> bytes:
        """The first ``n`` bytes of HMAC-SHA-256(key, data): a datagram's tag."""
        m = self._mac.copy()
        m.update(data)
        return m.digest()[:n]

    def __repr__(self) -> str:
        return f"LinkKey(fingerprint={self.fingerprint})"

    __str__ = __repr__

    def __reduce__(self):
        raise TypeError("a LinkKey is not pickled (a key never goes into a file but its own); pass the key file's "
                        "path and read it where it is used")


def _check_private(path: str) -> os.stat_result:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise KeyFileError(f"key file {path} does not exist; {KEYGEN_FIX}") from None
    except OSError as exc:
        raise KeyFileError(f"key file {path}: {exc.strerror}; {KEYGEN_FIX}") from None
    if stat.S_ISDIR(st.st_mode):
        raise KeyFileError(f"key file {path} is a folder; give the key file's path")
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(f"key file {path} is not a regular file; {KEYGEN_FIX}")
    if st.st_mode & 0o077:
        raise KeyFileError(f"key file {path} may be read by group or others (mode {stat.S_IMODE(st.st_mode):04o}); "
                           f"a rig's key is secret: run 'chmod 600 {path}'")
    return st


def parse_key_text(text: str, path: str = "key file") -> bytes:
    """The key bytes of a key file's text (comment lines ``#``, blank lines, one line of hex digits)."""
    lines = [ln.strip() for ln in text.splitlines()]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    if not body:
        raise KeyFileError(f"key file {path} holds no key (only comments or nothing); {KEYGEN_FIX}")
    if len(body) > 1:
        raise KeyFileError(f"key file {path} holds {len(body)} lines besides comments, a key file one; {KEYGEN_FIX}")
    digits = body[0]
    if any(c not in "0123456789abcdefABCDEF" for c in digits) or len(digits) % 2:
        raise KeyFileError(f"key file {path}: its key line is not an even number of hex digits; {KEYGEN_FIX}")
    n = len(digits) // 2
    if not MIN_KEY_BYTES <= n <= MAX_KEY_BYTES:
        raise KeyFileError(f"key file {path} holds a key of {n} bytes, a link key has {MIN_KEY_BYTES} to "
                           f"{MAX_KEY_BYTES}; {KEYGEN_FIX}")
    return bytes.fromhex(digits)


def read_key_file(path: str | os.PathLike) -> LinkKey:
    """The link key of a key file that only its owner may read.

    Raises:
        KeyFileError: missing, a folder, not a regular file, readable by group or others, too large, not text,
            or not one line of 32 to 128 hex digits; one line naming the file and the fix.
    """
    path = os.fspath(path)
    st = _check_private(path)
    if st.st_size == 0:
        raise KeyFileError(f"key file {path} is empty; {KEYGEN_FIX}")
    if st.st_size > MAX_FILE_BYTES:
        raise KeyFileError(f"key file {path} has {st.st_size} bytes, not a key file (at most {MAX_FILE_BYTES}); "
                           f"{KEYGEN_FIX}")
    try:
        with open(path, "rb") as f:
            text = f.read(MAX_FILE_BYTES).decode("ascii")
    except UnicodeDecodeError:
        raise KeyFileError(f"key file {path} is not text (binary data); {KEYGEN_FIX}") from None
    except OSError as exc:
        raise KeyFileError(f"key file {path}: {exc.strerror}") from None
    return LinkKey(parse_key_text(text, path))


def write_key_file(path: str | os.PathLike, secret: bytes | None = None) -> LinkKey:
    """Write a new key file (mode 0600, never over an existing file); returns its key.

    Args:
        path: the file to create.
        secret: the key; None draws KEY_BYTES from the operating system's random source.

    Raises:
        KeyFileError: the file exists, or its folder is missing or not writable.
    """
    path = os.fspath(path)
    secret = secrets.token_bytes(KEY_BYTES) if secret is None else bytes(secret)
    key = LinkKey(secret)
    text = (f"# ambid link key (HMAC-SHA-256, bridge protocol version 3); secret: keep it mode 0600\n"
            f"# fingerprint {key.fingerprint}\n{secret.hex()}\n")
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise KeyFileError(f"{path} exists; a rig's key is replaced on purpose only: remove the old file first, "
                           "or write the new one elsewhere") from None
    except OSError as exc:
        raise KeyFileError(f"cannot write the key file {path}: {exc.strerror}; give a path in a writable "
                           "folder") from None
    try:
        os.fchmod(fd, 0o600)  # whatever the umask
        os.write(fd, text.encode("ascii"))
    finally:
        os.close(fd)
    return key
