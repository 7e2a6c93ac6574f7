"""Message definitions as a log stores them: parsed into rosbags' type dictionaries, and the hash an output
format needs computed from them when the input does not carry it.

A ROS 1 bag stores each connection's definition and md5; a ROS 2 bag (version 8) its definition and RIHS01
hash; an MCAP file a schema (the definition) and no hash at all. A copy of an MCAP channel into a ROS 1 bag
therefore needs the md5, computed here from the stored definition as ROS 1 does (rosbags' ``generate_msgdef``),
and a copy into a ROS 2 bag the RIHS01 hash; a conversion to the other ROS version needs the types the
definition defines (the standard typestores lack a driver's own types, e.g. ``ouster_ros/PacketMsg``).
"""

from __future__ import annotations

from ...errors import InputError
from ..logs.base import LogConnection, first_line

_SEPARATOR = "=" * 80


def types_from_ros2msg(text: str, name: str) -> dict:
    """Parse a ros2msg schema: the main definition plus '=== MSG: pkg/Type' sub-definitions."""
    from rosbags.typesys import get_types_from_msg

    types: dict = {}
    parts = text.split(_SEPARATOR)
    types.update(get_types_from_msg(parts[0], name))
    for part in parts[1:]:
        part = part.strip()
        if not part.startswith("MSG:"):
            continue
        header, _, body = part.partition("\n")
        sub = header.split(":", 1)[1].strip()
        if "/msg/" not in sub:
            pkg, _, typ = sub.partition("/")
            sub = f"{pkg}/msg/{typ}"
        types.update(get_types_from_msg(body, sub))
    return types


def _types_from_idl(text: str) -> dict:
    """Parse a ros2idl definition: one IDL, or '=== IDL: pkg/msg/Type' sections (as rosbags' AnyReader)."""
    from rosbags.typesys import get_types_from_idl

    if not text.startswith(f"{_SEPARATOR}\nIDL: "):
        return get_types_from_idl(text)
    types: dict = {}
    for section in text.split(f"{_SEPARATOR}\n")[1:]:
        types.update(get_types_from_idl(section.split("\n", 1)[1] if "\n" in section else ""))
    return types


def stored_types(conn: LogConnection) -> dict:
    """Every type ``conn``'s stored definition defines (its own and those it uses; rosbags' ``Typesdict``), {}
    when the log stores none. A text that is no definition raises the parser's error (any exception)."""
    return types_of_definition(conn.msgdef, conn.msgdef_format, conn.msgtype) if conn.msgdef else {}


def types_of_definition(text: str, fmt: str, msgtype: str) -> dict:
    """The types a definition ``text`` of format ``fmt`` (ros2idl, ros2msg, else ROS 1 msg) defines for
    ``msgtype``; raises the parser's error on a text that is no definition."""
    from rosbags.typesys import get_types_from_msg

    if fmt == "ros2idl":
        return _types_from_idl(text)
    if fmt == "ros2msg":
        return types_from_ros2msg(text, msgtype)
    return get_types_from_msg(text, msgtype)


def stored_typestore(conn: LogConnection):
    """A typestore holding exactly the types ``conn``'s stored definition defines (None when it stores none or
    does not define ``conn.msgtype``); raises as ``stored_types``."""
    from rosbags.typesys import Stores, get_typestore

    types = stored_types(conn)
    if conn.msgtype not in types:
        return None
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    missing = _undefined(store.fielddefs, conn.msgtype)
    if missing is not None:
        raise ValueError(f"it uses {missing}, which it does not define")
    return store


def _undefined(fielddefs: dict, msgtype: str) -> str | None:
    """The first type ``msgtype`` uses, directly or through others, that ``fielddefs`` lacks (None: complete)."""
    from rosbags.interfaces import Nodetype

    seen, todo = set(), [msgtype]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        if name not in fielddefs:
            return name
        for _, (node, desc) in fielddefs[name][1]:
            if node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                node, desc = desc[0]
            if node == Nodetype.NAME:
                todo.append(desc)
    return None


class _Unusable(ValueError):
    """The stored definition could not be parsed (or lacks a type it uses): the parser's first line."""


def digest_of_definition(conn: LogConnection, ros_version: int) -> tuple[str, str] | None:
    """(definition, hash) of ``conn``'s type from its stored definition, or None when it stores none: for
    ROS 1 the definition as stored and its md5, for ROS 2 the definition as stored and its RIHS01 hash.
    Raises ``_Unusable`` when the stored text cannot be parsed or lacks a type it uses."""
    try:
        store = stored_typestore(conn)
    except Exception as err:  # noqa: BLE001 - rosbags' parser raises what it meets in the stored text
        raise _Unusable(first_line(err)) from err
    if store is None:
        return None
    if ros_version == 1:
        return conn.msgdef, store.generate_msgdef(conn.msgtype, ros_version=1)[1]
    return conn.msgdef, store.hash_rihs01(conn.msgtype)


def output_definition(conn: LogConnection, typestore, ros_version: int, where: str) -> tuple[str, str]:
    """(definition, hash) of ``conn``'s connection in a ROS ``ros_version`` output: both as stored where the
    input carries them, else the hash computed from the stored definition (an MCAP schema has none), else
    ``typestore``'s (a standard type, or one a conversion registered there from the input). What is really
    missing otherwise is refused (``where``: the message's prefix)."""
    if conn.msgdef and conn.digest:
        return conn.msgdef, conn.digest
    unusable = ""
    if conn.msgdef:
        try:
            found = digest_of_definition(conn, ros_version)
        except _Unusable as err:  # only the stored text's parse: a failure past it is a bug, not bad input
            found, unusable = None, str(err)
        if found is not None:
            return found
    msgtype = conn.msgtype
    if msgtype not in typestore.types:
        what = (f"the input's definition of {msgtype} cannot be used ({unusable or 'it does not define the type'})"
                if conn.msgdef else f"the input stores no definition of {msgtype}")
        raise InputError(f"{where}: {what} and it is not a standard type")
    if ros_version == 1:
        return typestore.generate_msgdef(msgtype)
    return typestore.generate_msgdef(msgtype, ros_version=2)[0], typestore.hash_rihs01(msgtype)


__all__ = ["digest_of_definition", "output_definition", "stored_types", "stored_typestore", "types_from_ros2msg",
           "types_of_definition"]
