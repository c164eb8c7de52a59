"""Message types of a bag: the typestore registered from the definitions the bag stores, and
those definitions checked against the standard ROS ones."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rosbags.interfaces import Connection, MessageDefinitionFormat, Nodetype
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore


def normalize_msgtype(msgtype: str) -> str:
    """Return a message type name in the ``pkg/msg/Name`` form.

    Parameters
    ----------
    msgtype : str
        ``pkg/Name`` (ROS 1 style) or ``pkg/msg/Name``.

    Returns
    -------
    str
        ``pkg/msg/Name``.
    """
    parts = msgtype.strip().strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)


_REFERENCE: Any = None


def _reference_store() -> Any:
    global _REFERENCE
    if _REFERENCE is None:
        _REFERENCE = get_typestore(Stores.LATEST)
    return _REFERENCE


def _field_kind(node: Any) -> str:
    """A field's type as text, e.g. ``uint32``, ``std_msgs/msg/Header``, ``float32[]``."""
    ntype, detail = node
    if ntype == Nodetype.BASE:
        return str(detail[0])
    if ntype == Nodetype.NAME:
        return str(detail)
    return f"{_field_kind(detail[0])}[{detail[1] if ntype == Nodetype.ARRAY else ''}]"


def definition_mismatch(store: Any, msgtype: str, depth: int = 0) -> str | None:
    """How the definition of ``msgtype`` in ``store`` departs from the standard ROS one.

    Every field of the standard definition must be present with the same type (extra fields,
    such as ROS 1's ``Header.seq``, are allowed). ``None`` if it conforms or is not standard.
    """
    ref = _reference_store().fielddefs.get(msgtype)
    own = store.fielddefs.get(msgtype)
    if ref is None or own is None or own is ref or depth > 8:
        return None
    fields = dict(own[1])
    for name, node in ref[1]:
        if name not in fields:
            return f"{msgtype} has no field {name!r}"
        want, got = _field_kind(node), _field_kind(fields[name])
        if want != got:
            return f"{msgtype} field {name!r} is {got}, expected {want}"
        sub = node
        while sub[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            sub = sub[1][0]
        if sub[0] == Nodetype.NAME:
            why = definition_mismatch(store, str(sub[1]), depth + 1)
            if why:
                return why
    return None


def register_types(connections: Iterable[Connection]) -> tuple[Any, set[str]]:
    """Typestore with the types defined in the bag, and the types lacking a definition."""
    typs: dict[str, Any] = {}
    lacking: set[str] = set()
    for conn in connections:
        fmt = conn.msgdef.format
        if fmt == MessageDefinitionFormat.MSG:
            typs.update(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        elif fmt == MessageDefinitionFormat.IDL:
            sep = "=" * 80 + "\n"
            if conn.msgdef.data.startswith(f"{sep}IDL: "):
                for block in conn.msgdef.data.split(sep)[1:]:
                    typs.update(get_types_from_idl(block.split("\n", 1)[1]))
            else:
                typs.update(get_types_from_idl(conn.msgdef.data))
        else:
            lacking.add(conn.msgtype)
    store = get_typestore(Stores.EMPTY)
    store.register(typs)
    return store, lacking - set(typs)
