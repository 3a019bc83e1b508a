"""The C target's SHA-256 and HMAC-SHA-256 (ambid_core/target_c/ambp_hmac.c), through the libambp.so that
`ambid setup` builds: the FIPS 180-4 example messages and the RFC 4231 test cases, their digests copied from
those documents; then random messages and keys of every length that matters (padding boundaries, keys
longer than a block) against Python's hashlib and hmac; the constant-time comparison."""

from __future__ import annotations

import ctypes
import hashlib
import hmac
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
LIB = ROOT / "ros_ws" / "install" / "target_c" / "libambp.so"

# FIPS 180-4's SHA-256 examples (NIST CSRC "Example Algorithms", SHA256.pdf and SHA2_Additional.pdf)
FIPS_180_4 = [
    (b"abc", "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"),
    (b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq",
     "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"),
    (b"abcdefghbcdefghicdefghijdefghijkefghijklfghijklmghijklmnhijklmnoijklmnopjklmnopqklmnopqrlmnopqrs"
     b"mnopqrstnopqrstu", "cf5b16a778af8380036ce59e7b0492370b249b11e8f07a51afac45037afee9d1"),
    (b"", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"),
    (b"a" * 1_000_000, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0"),
]

# RFC 4231, section 4: HMAC-SHA-256 test cases 1 to 7 (case 5's output truncated to 128 bits)
RFC_4231 = [
    (b"\x0b" * 20, b"Hi There", "b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7"),
    (b"Jefe", b"what do ya want for nothing?", "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"),
    (b"\xaa" * 20, b"\xdd" * 50, "773ea91e36800e46854db8ebd09181a72959098b3ef8c122d9635514ced565fe"),
    (bytes(range(1, 26)), b"\xcd" * 50, "82558a389a443c0ea4cc819899f2083a85f0faa3e578f8077a2e3ff46729665b"),
    (b"\x0c" * 20, b"Test With Truncation", "a3b6167473100ee06e0c796c2955552b"),
    (b"\xaa" * 131, b"Test Using Larger Than Block-Size Key - Hash Key First",
     "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54"),
    (b"\xaa" * 131, b"This is a test using a larger than block-size key and a larger than block-size data. The key "
                    b"needs to be hashed before being used by the HMAC algorithm.",
     "9b09ffa71b942fcb27635fbcd5b0e944bfdc63644f0713938a7f51535c3a35e2"),
]


@pytest.fixture(scope="module")
def lib():
    assert LIB.is_file(), f"{LIB} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    so = ctypes.CDLL(str(LIB))
    for name in ("ambp_sha256",):
        getattr(so, name).argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p]
    so.ambp_hmac_sha256.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t,
                                    ctypes.c_char_p]
    so.ambp_equal_ct.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t]
    so.ambp_equal_ct.restype = ctypes.c_int
    return so


def sha256(lib, data: bytes) -> bytes:
    out = ctypes.create_string_buffer(32)
    lib.ambp_sha256(data, len(data), out)
    return out.raw


def hmac_sha256(lib, key: bytes, data: bytes) -> bytes:
    out = ctypes.create_string_buffer(32)
    lib.ambp_hmac_sha256(key, len(key), data, len(data), out)
    return out.raw


def test_sha256_gives_the_fips_180_4_examples(lib):
    for message, digest in FIPS_180_4:
        assert sha256(lib, message).hex() == digest, message[:20]


def test_hmac_sha256_gives_the_rfc_4231_test_cases(lib):
    for i, (key, data, tag) in enumerate(RFC_4231, 1):
        assert hmac_sha256(lib, key, data).hex()[:len(tag)] == tag, f"RFC 4231 test case {i}"


def test_every_padding_boundary_and_key_length_agrees_with_python(lib):
    rng = np.random.default_rng(4231)
    # messages across the 55/56/63/64-byte padding edges and a datagram's sizes; keys empty to beyond a block
    for n in [*range(0, 200), 1350, 1471, 1472, 4096]:
        data = rng.bytes(n)
        assert sha256(lib, data) == hashlib.sha256(data).digest(), n
        for key_len in (0, 1, 16, 32, 63, 64, 65, 131) if n < 130 or n > 1000 else (32,):
            key = rng.bytes(key_len)
            assert hmac_sha256(lib, key, data) == hmac.new(key, data, hashlib.sha256).digest(), (n, key_len)


def test_tag_comparison_looks_at_every_byte(lib):
    a = bytes(range(16))
    assert lib.ambp_equal_ct(a, a, 16) == 1
    for i in range(16):  # a difference anywhere, the first byte or the last, is found
        b = bytearray(a)
        b[i] ^= 0x80
        assert lib.ambp_equal_ct(a, bytes(b), 16) == 0
    assert lib.ambp_equal_ct(a, b"\xff" * 16, 0) == 1


def test_comparison_takes_the_same_time_wherever_the_tags_differ(lib):
    # an early exit (memcmp) would answer a difference in the first byte in nanoseconds and the same buffers
    # in milliseconds; ambp_equal_ct reads every byte whatever it has found. 4 MiB make one comparison a few
    # milliseconds, the shortest of several runs each (interleaved, on a busy machine) compares like with like.
    import time

    n = 1 << 22
    a = bytes(n)
    cases = {"equal": a, "first byte": b"\x01" + bytes(n - 1),
             "middle byte": bytes(n // 2) + b"\x01" + bytes(n // 2 - 1), "last byte": bytes(n - 1) + b"\x01"}
    best = dict.fromkeys(cases, float("inf"))
    for _ in range(9):
        for name, b in cases.items():
            t0 = time.perf_counter()
            same = lib.ambp_equal_ct(a, b, n)
            best[name] = min(best[name], time.perf_counter() - t0)
            assert same == (name == "equal"), name
    assert max(best.values()) < 2.0 * min(best.values()), best


def test_the_protocol_core_allocates_nothing_and_calls_no_os(lib):
    # libambp.so is the core a target links (ambp.c, ambp_hmac.c): what it imports from the C library is all
    # it can call. Only memory copies and maths: no allocator, no clock, no socket, no file.
    import shutil
    import subprocess

    assert shutil.which("nm"), "nm (binutils, which gcc brings) is missing"
    out = subprocess.run(["nm", "-D", "--undefined-only", str(LIB)], capture_output=True, text=True, check=True)
    imported = {line.split()[-1].split("@")[0] for line in out.stdout.splitlines()
                if line.split() and line.split()[0] == "U"}
    allowed = {"memcpy", "memmove", "memset", "memcmp", "__stack_chk_fail", "__memcpy_chk", "__memset_chk",
               "__memmove_chk"} | {"sqrt", "sin", "cos", "exp", "log", "pow", "fabs", "floor", "ceil", "round",
                                   "lround", "llround", "fmod", "nan", "isnan"}
    assert imported and imported <= allowed, sorted(imported - allowed)
