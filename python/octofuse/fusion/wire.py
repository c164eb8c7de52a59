"""A message between two agents as bytes: a small versioned header, then the payload.

Every link carries the same frame, in process (a swarm's actors) or over a network::

    offset  size  field
    0       4     magic b"OFM" + version (1)
    4       1     kind: whole map, delta, acknowledgement (:class:`Kind`)
    5       1     encoding of the payload: OctoMap's binary ``.ot`` stream, or several of
                  them as source layers (:class:`Encoding`)
    6       2     reserved, zero
    8       8     sequence number of this message on its link and direction (1, 2, ...)
    16      8     acknowledgement: the newest sequence number the sender has applied from the
                  receiver (0: none)
    24      4     payload length in bytes
    28      4     CRC-32 of every byte of the frame but these four
    32      ...   fleet, rule, sender, receiver: each a length byte and UTF-8 text
    ...     ...   payload

A payload of source layers (``LAYERS``, :func:`encode_layers`) is a count (4 bytes), then per
layer: its source (a length byte and UTF-8 text), version (8 bytes), base version (8 bytes; 0:
the whole layer, otherwise a delta against that version), flags (1 byte: 1 = the version only,
no map) and the length (4 bytes) and bytes of its ``.ot`` stream.

All integers are little-endian. :func:`decode` refuses, with :class:`WireError` (a
``ValueError``) naming what is wrong, a frame that is truncated, has trailing bytes, another
magic or version, an unknown kind or encoding, a payload over the caller's bound, or a checksum
that does not match: a receiver drops and counts such frames and never fuses them.
"""

from __future__ import annotations

import enum
import struct
import zlib
from dataclasses import dataclass

MAGIC = b"OFM"
VERSION = 1
_FIXED = struct.Struct("<3sBBBH QQ II")
#: bytes of the fixed part of the header (the names follow it)
HEADER_BYTES = _FIXED.size
_CRC_AT = HEADER_BYTES - 4
#: the largest payload a receiver takes unless it says otherwise
DEFAULT_MAX_PAYLOAD = 256 * 2**20
_MAX_NAME = 255


class WireError(ValueError):
    """A frame that is not a well-formed message (truncated, corrupted, foreign or too big)."""


class Kind(enum.IntEnum):
    """What a message carries."""

    WHOLE = 1  #: the sender's whole map (or channel-filter contribution)
    DELTA = 2  #: only the voxels changed since the last acknowledged message on the link
    ACK = 3  #: no payload: acknowledges the receiver's messages up to ``ack``


class Encoding(enum.IntEnum):
    """How the payload is written."""

    NONE = 0  #: no payload (an acknowledgement)
    OCTOMAP_OT = 1  #: OctoMap's binary ``.ot`` stream of an ``OcTree`` (log-odds per node)
    LAYERS = 2  #: per source: its version and its ``.ot`` stream, whole or a delta


@dataclass(frozen=True)
class Message:
    """One message on a link (``payload``: the encoded map, empty for an acknowledgement)."""

    fleet: str
    rule: str
    sender: str
    receiver: str
    seq: int
    ack: int
    kind: Kind
    payload: bytes = b""
    encoding: Encoding = Encoding.OCTOMAP_OT

    def encode(self) -> bytes:
        """The message as one frame of bytes."""
        names = b"".join(
            _name(v, f)
            for f, v in (
                ("fleet", self.fleet),
                ("rule", self.rule),
                ("sender", self.sender),
                ("receiver", self.receiver),
            )
        )
        for field, v in (("seq", self.seq), ("ack", self.ack)):
            if not 0 <= v < 2**64:
                raise ValueError(f"message {field} = {v}: expected 0 to 2**64 - 1")
        if len(self.payload) >= 2**32:
            raise ValueError(f"message payload of {len(self.payload)} bytes: expected under 4 GiB")
        head = _FIXED.pack(
            MAGIC,
            VERSION,
            int(self.kind),
            int(self.encoding),
            0,
            self.seq,
            self.ack,
            len(self.payload),
            0,
        )
        crc = zlib.crc32(self.payload, zlib.crc32(names, zlib.crc32(head[:_CRC_AT])))
        return b"".join((head[:_CRC_AT], struct.pack("<I", crc), names, self.payload))


def decode(
    frame: bytes | bytearray | memoryview, max_payload: int = DEFAULT_MAX_PAYLOAD
) -> Message:
    """The message of one frame; :class:`WireError` if it is not a well-formed message."""
    view = memoryview(frame)
    if len(view) < HEADER_BYTES:
        raise WireError(f"frame of {len(view)} bytes: shorter than the {HEADER_BYTES}-byte header")
    magic, version, kind, encoding, reserved, seq, ack, length, crc = _FIXED.unpack_from(view)
    if magic != MAGIC:
        raise WireError(f"frame starts with {bytes(magic)!r}: not an octofuse message")
    if version != VERSION:
        raise WireError(f"message version {version}: this octofuse reads version {VERSION}")
    if kind not in Kind._value2member_map_:
        raise WireError(
            f"message kind {kind}: expected one of "
            f"{', '.join(f'{k.value} ({k.name})' for k in Kind)}"
        )
    if encoding not in Encoding._value2member_map_:
        raise WireError(
            f"payload encoding {encoding}: expected one of "
            f"{', '.join(f'{e.value} ({e.name})' for e in Encoding)}"
        )
    if reserved:
        raise WireError(f"reserved header bytes are {reserved}: expected 0")
    if length > max_payload:
        raise WireError(f"payload of {length} bytes: over the bound of {max_payload} bytes")
    at, names = HEADER_BYTES, []
    for field in ("fleet", "rule", "sender", "receiver"):
        if at >= len(view):
            raise WireError(f"frame truncated in the {field} name")
        n = view[at]
        text = bytes(view[at + 1 : at + 1 + n])
        if len(text) != n:
            raise WireError(f"frame truncated in the {field} name")
        try:
            names.append(text.decode("utf-8"))
        except UnicodeDecodeError:
            raise WireError(f"the {field} name is not UTF-8 text") from None
        at += 1 + n
    if len(view) - at != length:
        raise WireError(f"payload of {len(view) - at} bytes where the header says {length}")
    want = zlib.crc32(view[HEADER_BYTES:], zlib.crc32(view[:_CRC_AT]))
    if want != crc:
        raise WireError(f"checksum {crc:#010x} does not match the frame's {want:#010x}")
    payload = bytes(view[at:])
    if encoding == Encoding.LAYERS:
        decode_layers(payload)  # refused here, before anything reads it
    if (kind == Kind.ACK) != (encoding == Encoding.NONE) or (kind == Kind.ACK and payload):
        raise WireError("an acknowledgement carries no payload, and only it")
    return Message(*names, seq, ack, Kind(kind), payload, Encoding(encoding))


def _name(value: str, field: str) -> bytes:
    data = str(value).encode("utf-8")
    if len(data) > _MAX_NAME:
        raise ValueError(f"message {field} {value!r}: over {_MAX_NAME} bytes of UTF-8")
    return bytes([len(data)]) + data


@dataclass(frozen=True)
class LayerBlob:
    """One source's layer in a ``LAYERS`` payload: ``data`` its ``.ot`` stream (whole if
    ``base`` is 0, else a delta against version ``base``), or with ``held`` no data: the
    sender holds that version."""

    source: str
    version: int
    base: int = 0
    data: bytes = b""
    held: bool = False


_LAYER = struct.Struct("<QQBI")


def encode_layers(layers: list[LayerBlob]) -> bytes:
    """A ``LAYERS`` payload of ``layers``."""
    out = [struct.pack("<I", len(layers))]
    for x in layers:
        for field, v in (("version", x.version), ("base", x.base)):
            if not 0 <= v < 2**64:
                raise ValueError(f"layer {field} = {v}: expected 0 to 2**64 - 1")
        if x.held and x.data:
            raise ValueError(f"layer {x.source!r}: a version without a map carries no data")
        out += [
            _name(x.source, "layer source"),
            _LAYER.pack(x.version, x.base, int(x.held), len(x.data)),
            x.data,
        ]
    return b"".join(out)


def decode_layers(payload: bytes | bytearray | memoryview) -> list[LayerBlob]:
    """The layers of a ``LAYERS`` payload; :class:`WireError` if it is not one."""
    view = memoryview(payload)
    if len(view) < 4:
        raise WireError(f"layers payload of {len(view)} bytes: shorter than its count")
    (n,), at, out = struct.unpack_from("<I", view), 4, []
    for k in range(n):
        if at >= len(view):
            raise WireError(f"layers payload truncated at layer {k} of {n}")
        size = view[at]
        text = bytes(view[at + 1 : at + 1 + size])
        at += 1 + size
        if len(text) != size or at + _LAYER.size > len(view):
            raise WireError(f"layers payload truncated at layer {k} of {n}")
        try:
            source = text.decode("utf-8")
        except UnicodeDecodeError:
            raise WireError(f"layer {k}'s source is not UTF-8 text") from None
        version, base, flags, length = _LAYER.unpack_from(view, at)
        at += _LAYER.size
        if flags not in (0, 1) or (flags and length):
            raise WireError(f"layer {k}: flags {flags} with {length} bytes of map")
        if at + length > len(view):
            raise WireError(f"layers payload truncated in layer {k}'s map")
        out.append(LayerBlob(source, version, base, bytes(view[at : at + length]), bool(flags)))
        at += length
    if at != len(view):
        raise WireError(f"layers payload has {len(view) - at} bytes after its {n} layers")
    return out
