"""ROS 2 message definitions and type hashes as rosbag2 stores them in MCAP.

rosbag2 (``rosbag2_cpp::LocalMessageDefinitionSource``) stores, for each topic
type, the type's ``.msg`` text followed by every nested non-primitive type's
``.msg`` text, each introduced by a separator line and ``MSG: pkg/Type``::

    <root .msg text>
    ================================================================================
    MSG: std_msgs/MultiArrayLayout
    <MultiArrayLayout.msg text>
    ================================================================================
    MSG: std_msgs/MultiArrayDimension
    <MultiArrayDimension.msg text>

Dependencies are visited depth first, the direct dependencies of one type in
sorted (bytewise) order, each type at most once. The same order is used here
so that a session written by ambid carries the schema text rosbag2 would have
written.

Definitions are looked up as ``<prefix>/share/<pkg>/msg/<Type>.msg`` for each
prefix of ``AMENT_PREFIX_PATH``; the RIHS01 type hash is read from the
``<Type>.json`` file rosidl generates next to it (key ``type_hashes``). Both
can also be supplied directly, for types that are not installed.

Pure Python; nothing here imports rclpy.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

__all__ = [
    "DEFINITION_SEPARATOR",
    "PRIMITIVE_TYPES",
    "MessageSchema",
    "ament_prefixes",
    "normalize_type_name",
    "split_type_name",
    "nested_type_names",
    "find_interface_file",
    "read_message_definition",
    "read_type_hash",
    "full_message_definition",
    "split_full_definition",
    "load_message_schema",
]

#: Line that separates the definitions in a ros2msg schema (80 '=').
DEFINITION_SEPARATOR = "=" * 80

#: Field types of the ROS 2 .msg language that are not messages.
PRIMITIVE_TYPES = frozenset(
    {
        "bool", "byte", "char", "float32", "float64", "int8", "uint8",
        "int16", "uint16", "int32", "uint32", "int64", "uint64",
        "string", "wstring",
    }
)

_NAME = r"[A-Za-z][A-Za-z0-9_]*"
_TYPE_RE = re.compile(rf"^({_NAME})(?:/({_NAME}))?(?:/({_NAME}))?$")
# Longest recursion rosbag2 accepts before giving up (it guards cycles the same way).
_MAX_DEPTH = 50


@dataclass(frozen=True)
class MessageSchema:
    """Everything a ``ros2`` profile MCAP needs to know about one message type.

    Attributes
    ----------
    type_name
        full ROS 2 name, ``pkg/msg/Type``.
    definition
        ``ros2msg`` schema text: the type's .msg text followed by
        every nested type's text, rosbag2-style.
    type_hash
        ``RIHS01_<64 hex>``, or ``""`` when unknown.
    dependencies
        nested type names (``pkg/Type``) in the order their
        definitions appear in ``definition``.
    """

    type_name: str
    definition: str
    type_hash: str
    dependencies: tuple[str, ...]


def ament_prefixes(ament_prefix_path: str | None = None) -> list[Path]:
    """Install prefixes listed in ``AMENT_PREFIX_PATH`` (or in the given string).

    Parameters
    ----------
    ament_prefix_path
        ``os.pathsep``-separated prefixes; ``None`` reads the
        ``AMENT_PREFIX_PATH`` environment variable.

    Returns
    -------
    The prefixes in search order, empty entries dropped.
    """
    text = os.environ.get("AMENT_PREFIX_PATH", "") if ament_prefix_path is None else ament_prefix_path
    return [Path(p) for p in text.split(os.pathsep) if p]


#: the message definitions this library carries (``share/<pkg>/msg/*.msg`` as rosidl installs them): the
#: last place searched, so the core reads and writes sessions where no ROS workspace is sourced
#: (``pip install ./ambid_core``); ``ambid_msgs/msg`` is their one source (a symlink here, copied into the wheel)
PACKAGED_PREFIX = Path(__file__).resolve().parent.parent / "interfaces"


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """Split ``pkg/msg/Type`` or ``pkg/Type`` into ``(pkg, "msg", Type)``.

    Raises
    ------
    ValueError
        if the name is not of either form, or its middle part is
        not ``msg`` (services and actions have no topic definitions).
    """
    match = _TYPE_RE.match(type_name.strip()) if isinstance(type_name, str) else None
    if match is None or match.group(2) is None:
        raise ValueError(
            f"type name {type_name!r} is not of the form 'pkg/msg/Type' or 'pkg/Type'; "
            "pass the full ROS 2 type name, e.g. 'std_msgs/msg/String'"
        )
    pkg, second, third = match.groups()
    if third is None:
        return pkg, "msg", second
    if second != "msg":
        raise ValueError(
            f"type name {type_name!r} is not a message type (middle part {second!r}, "
            "expected 'msg'); only message types can be recorded"
        )
    return pkg, "msg", third


def normalize_type_name(type_name: str) -> str:
    """Full ROS 2 name ``pkg/msg/Type`` of ``pkg/Type`` or ``pkg/msg/Type``."""
    pkg, ns, name = split_type_name(type_name)
    return f"{pkg}/{ns}/{name}"


def _short_name(type_name: str) -> str:
    pkg, _, name = split_type_name(type_name)
    return f"{pkg}/{name}"


def _field_base_type(token: str) -> str:
    """Element type of a field type token: drops ``[...]`` and ``<=N``."""
    base = re.sub(r"\[[^\]]*\]$", "", token)
    return base.split("<=", 1)[0]


def nested_type_names(definition: str, package: str) -> list[str]:
    """Non-primitive field types used by one .msg definition.

    Comment and blank lines are skipped; constants (``uint8 A=1``) are
    primitive by the language rules, so they never add a dependency; array
    suffixes (``[]``, ``[3]``, ``[<=5]``) and string bounds (``string<=8``)
    are removed; a type written without package (``Inner``) belongs to
    ``package``, as rosidl resolves it.

    Parameters
    ----------
    definition
        text of one .msg file (no ``MSG:`` sections).
    package
        package the definition belongs to.

    Returns
    -------
    Sorted (bytewise, like rosbag2's ``std::set``) unique ``pkg/Type``
    names.

    Raises
    ------
    ValueError
        if a field type is not a valid ROS 2 type name.
    """
    found: set[str] = set()
    for lineno, raw in enumerate(definition.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        base = _field_base_type(line.split()[0])
        if base in PRIMITIVE_TYPES:
            continue
        if "/" not in base:
            base = f"{package}/{base}"
        try:
            found.add(_short_name(base))
        except ValueError as exc:
            raise ValueError(
                f"line {lineno} of a {package} definition has field type {line.split()[0]!r}, "
                "which is neither a primitive nor a 'pkg/Type' message name"
            ) from exc
    return sorted(found)


def find_interface_file(type_name: str, extension: str, prefixes: Sequence[Path] | None = None) -> Path:
    """Path of ``<prefix>/share/<pkg>/msg/<Type><extension>`` in the first prefix that has it.

    Parameters
    ----------
    type_name
        ``pkg/msg/Type`` or ``pkg/Type``.
    extension
        ``".msg"`` or ``".json"``.
    prefixes
        install prefixes; ``None`` uses ``AMENT_PREFIX_PATH``, then the definitions
        this library carries (:data:`PACKAGED_PREFIX`).

    Raises
    ------
    FileNotFoundError
        naming the type, the file and the prefixes searched.
    """
    pkg, ns, name = split_type_name(type_name)
    search = [*ament_prefixes(), PACKAGED_PREFIX] if prefixes is None else [Path(p) for p in prefixes]
    for prefix in search:
        candidate = prefix / "share" / pkg / ns / f"{name}{extension}"
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"no share/{pkg}/{ns}/{name}{extension} for {pkg}/{ns}/{name} in the install prefixes "
        f"{[str(p) for p in search]}; source the workspace that builds {pkg} (AMENT_PREFIX_PATH) "
        "or pass the definition/type hash directly"
    )


def read_message_definition(type_name: str, prefixes: Sequence[Path] | None = None) -> str:
    """Text of the installed ``.msg`` file of ``type_name`` (unchanged bytes, UTF-8)."""
    return find_interface_file(type_name, ".msg", prefixes).read_text(encoding="utf-8")


def read_type_hash(type_name: str, prefixes: Sequence[Path] | None = None) -> str:
    """RIHS01 type hash of ``type_name`` from the rosidl-generated ``<Type>.json``.

    Returns
    -------
    ``"RIHS01_<64 hex>"``.

    Raises
    ------
    FileNotFoundError
        if no .json is installed for the type.
    ValueError
        if the .json lists no hash for the type.
    """
    full = normalize_type_name(type_name)
    path = find_interface_file(full, ".json", prefixes)
    with open(path, encoding="utf-8") as f:
        doc = json.load(f)
    for entry in doc.get("type_hashes", []):
        if entry.get("type_name") == full:
            return str(entry["hash_string"])
    raise ValueError(f"{path} has no entry for {full} under 'type_hashes'; regenerate the package's interfaces")


def _lookup_definition(
    type_name: str, definitions: Mapping[str, str], prefixes: Sequence[Path] | None
) -> str:
    short = _short_name(type_name)
    if short in definitions:
        return definitions[short]
    return read_message_definition(type_name, prefixes)


def full_message_definition(
    type_name: str,
    prefixes: Sequence[Path] | None = None,
    definitions: Mapping[str, str] | None = None,
) -> tuple[str, tuple[str, ...]]:
    """rosbag2-style ``ros2msg`` schema text of ``type_name`` and its dependency order.

    Parameters
    ----------
    type_name
        ``pkg/msg/Type`` or ``pkg/Type``.
    prefixes
        install prefixes; ``None`` uses ``AMENT_PREFIX_PATH``.
    definitions
        single-type .msg texts keyed by type name (either form);
        they take precedence over installed files, so types that are not
        installed can be used.

    Returns
    -------
    ``(text, dependencies)``: the root text followed by each nested type's
    text, and the ``pkg/Type`` names in the order they were appended.

    Raises
    ------
    FileNotFoundError
        if a definition is neither given nor installed.
    ValueError
        on malformed type names or a dependency chain deeper
        than 50 (a cycle).
    """
    given = {_short_name(k): v for k, v in (definitions or {}).items()}
    seen: set[str] = set()
    order: list[str] = []

    def append(short: str, depth: int) -> str:
        if depth <= 0:
            raise ValueError(f"message definitions of {type_name} nest deeper than {_MAX_DEPTH}: a cycle?")
        text = _lookup_definition(short, given, prefixes)
        out = text
        for dep in nested_type_names(text, short.split("/")[0]):
            if dep not in seen:
                seen.add(dep)
                order.append(dep)
                out += f"\n{DEFINITION_SEPARATOR}\nMSG: {dep}\n" + append(dep, depth - 1)
        return out

    text = append(_short_name(type_name), _MAX_DEPTH)
    return text, tuple(order)


def split_full_definition(text: str) -> dict[str | None, str]:
    """Split a rosbag2-style schema text into its single-type definitions.

    Returns
    -------
    ``{None: root text, "pkg/Type": text, ...}`` in file order; the texts
    are exactly what :func:`full_message_definition` concatenated.
    """
    sections: dict[str | None, str] = {}
    parts = text.split(f"\n{DEFINITION_SEPARATOR}\n")
    sections[None] = parts[0]
    for part in parts[1:]:
        header, _, body = part.partition("\n")
        if not header.startswith("MSG: "):
            raise ValueError(f"schema section starts with {header!r}, expected 'MSG: pkg/Type'")
        sections[header[len("MSG: "):].strip()] = body
    return sections


def load_message_schema(
    type_name: str,
    prefixes: Sequence[Path] | None = None,
    definitions: Mapping[str, str] | None = None,
    type_hash: str | None = None,
) -> MessageSchema:
    """Schema text and type hash of ``type_name``, ready for the MCAP writer.

    Parameters
    ----------
    type_name, prefixes, definitions
        as :func:`full_message_definition`'s.
    type_hash
        ``RIHS01_...`` to use; ``None`` reads the installed .json
        and falls back to ``""`` when there is none (the hash is optional
        in rosbag2 files, the definition is not).

    Raises
    ------
    ValueError
        on a malformed ``type_hash`` or type name.
    FileNotFoundError
        if a needed definition is neither given nor installed.
    """
    full = normalize_type_name(type_name)
    text, deps = full_message_definition(full, prefixes, definitions)
    if type_hash is None:
        try:
            type_hash = read_type_hash(full, prefixes)
        except (FileNotFoundError, ValueError):
            type_hash = ""
    elif type_hash and not re.fullmatch(r"RIHS01_[0-9a-f]{64}", type_hash):
        raise ValueError(
            f"type hash {type_hash!r} of {full} is not 'RIHS01_' followed by 64 lowercase hex digits"
        )
    return MessageSchema(type_name=full, definition=text, type_hash=type_hash, dependencies=deps)
