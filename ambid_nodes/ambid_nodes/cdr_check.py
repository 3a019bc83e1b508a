"""Whether serialized bytes would make rosidl's deserializer write to stderr, checked before it runs.

rosidl's Fast DDS typesupport writes a line to the process's stderr for some
bytes it cannot deserialize ("sequence size exceeds remaining buffer", "string
not null-terminated", "array size exceeds upper bound"), naming neither the
node nor the topic. The nodes take every message raw (``ambid_nodes.intake``)
and walk it here first: what would not deserialize is rejected with its reason
and counted per topic like any other bad message, and rosidl only sees bytes
that fit the type. The walk follows the XCDR1 layout rosidl uses: a 4-byte
encapsulation header (00 00 big endian, 00 01 little endian), then the fields
in order, each aligned to its size relative to the body (strings and sequence
lengths as uint32, a string's bytes ending in its NUL). It refuses what rosidl
would print about (a sequence length beyond the bytes left, a bound
exceeded, a wrong header); where the bytes end early otherwise, rosidl's Fast
CDR raises quietly and ``decode_message`` reports its error. Trailing bytes
are allowed, as rosidl allows them. Cost: a few microseconds per field walked; a
sequence of numbers is one length check, whatever its size.
"""

from __future__ import annotations

import importlib
import struct
from functools import lru_cache

from rosidl_parser.definition import (AbstractGenericString, AbstractNestedType, AbstractSequence,
                                      AbstractWString, Array, BasicType, BoundedSequence, BoundedString,
                                      NamespacedType)

_SIZES = {"boolean": 1, "octet": 1, "char": 1, "uint8": 1, "int8": 1, "wchar": 2, "uint16": 2, "int16": 2,
          "uint32": 4, "int32": 4, "float": 4, "uint64": 8, "int64": 8, "double": 8, "long double": 16}

__all__ = ["cdr_problem"]


class _Bad(Exception):
    pass


class _Stop(Exception):
    """The walk cannot go on, but rosidl refuses these bytes quietly (Fast CDR raises, rmw reports it)."""


@lru_cache(maxsize=None)
def _fields(msg_type) -> tuple:
    return tuple(zip(msg_type.get_fields_and_field_types(), msg_type.SLOT_TYPES))


@lru_cache(maxsize=None)
def _nested(namespaces: tuple, name: str):
    return getattr(importlib.import_module(".".join(namespaces)), name)


class _Walk:
    __slots__ = ("data", "pos", "end", "u32")

    def __init__(self, data: bytes) -> None:
        self.data, self.pos, self.end = data, 4, len(data)
        self.u32 = struct.Struct("<I" if data[1] == 1 else ">I").unpack_from

    def skip(self, size: int, count: int, what: str) -> None:
        """``count`` items of ``size`` bytes at the next multiple of ``size`` in the body."""
        align = min(size, 8)
        pos = 4 + (self.pos - 4 + align - 1) // align * align if count else self.pos
        end = pos + size * count
        if end > self.end:
            raise _Stop(f"{what} runs past the end ({count} x {size} bytes from byte {pos} of {self.end})")
        self.pos = end

    def count(self, what: str) -> int:
        self.skip(4, 1, f"{what}'s length")
        return self.u32(self.data, self.pos - 4)[0]

    def string(self, what: str, bound: int | None = None, wide: bool = False) -> None:
        n = self.count(what)
        self.skip(2 if wide else 1, n, f"{what} ({n} characters)")
        if bound is not None and n - 1 > bound:
            raise _Bad(f"{what} has {n - 1} characters, at most {bound} allowed")

    def value(self, t, what: str, times: int = 1) -> None:
        if isinstance(t, BasicType):
            self.skip(_SIZES[t.typename], times, what)
        elif isinstance(t, AbstractGenericString):
            bound = t.maximum_size if isinstance(t, BoundedString) else None
            for i in range(times):
                self.string(what if times == 1 else f"{what}[{i}]", bound, isinstance(t, AbstractWString))
        elif isinstance(t, NamespacedType):
            fields = _fields(_nested(tuple(t.namespaces), t.name))
            for _ in range(times):
                self.message(fields, what + ".")
        elif isinstance(t, Array):
            self.value(t.value_type, what, times * t.size)
        elif isinstance(t, AbstractSequence):
            for _ in range(times):
                n = self.count(what)
                if n > self.end - self.pos:  # what rosidl checks, and prints about
                    raise _Bad(f"{what} says {n} elements, more than the {self.end - self.pos} bytes left")
                if isinstance(t, BoundedSequence) and n > t.maximum_size:
                    raise _Bad(f"{what} has {n} elements, at most {t.maximum_size} allowed")
                self.value(t.value_type, what, n)
        elif isinstance(t, AbstractNestedType):  # pragma: no cover - every rosidl kind is handled above
            raise _Bad(f"{what}: unknown field kind {type(t).__name__}")

    def message(self, fields: tuple, prefix: str = "") -> None:
        for name, t in fields:
            self.value(t, prefix + name)


def cdr_problem(data: bytes, msg_type) -> str | None:
    """None if ``data`` walks as a serialized ``msg_type``, else what is wrong (one phrase)."""
    if len(data) < 4:
        return f"{len(data)} bytes, too short for a CDR header"
    if data[0] != 0 or data[1] not in (0, 1):
        return f"unexpected CDR encapsulation {bytes(data[:4]).hex()}"
    try:
        _Walk(data).message(_fields(msg_type))
    except _Bad as exc:
        return str(exc)
    except _Stop:
        return None  # rosidl refuses it without a word on stderr: its error names the rest
    return None
