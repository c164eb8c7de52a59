"""Messages cut into chunks of a bounded size for the link, and put together again.

A lossy radio loses a large message more often than a small one; cut into chunks, a message
whose chunk is lost is simply not complete, is never applied, and the link protocol sends its
content again (nothing is acknowledged that did not arrive). Each chunk::

    offset  size  field
    0       4     magic b"OFC" + version (1)
    4       8     message number (per sender)
    12      2     chunk index
    14      2     chunk count
    16      4     the whole message's length
    20      ...   the chunk's bytes

A receiver keeps the incomplete messages of a sender (a few, the newest; bounded in bytes) and
drops a chunk that does not fit what it announced; the whole message's own checksum
(:mod:`octofuse.fusion.wire`) catches anything else.
"""

from __future__ import annotations

import struct
from collections import OrderedDict

MAGIC = b"OFC"
VERSION = 1
_HEAD = struct.Struct("<3sB Q HH I")
HEAD_BYTES = _HEAD.size
#: incomplete messages a receiver keeps per sender (the oldest go first)
KEEP = 4


def split(frame: bytes, number: int, max_bytes: int) -> list[bytes]:
    """``frame`` as chunks of at most ``max_bytes`` bytes each, header included."""
    room = max_bytes - HEAD_BYTES
    if room <= 0:
        raise ValueError(f"chunks of {max_bytes} bytes: expected more than {HEAD_BYTES}")
    count = max(1, -(-len(frame) // room))
    if count > 0xFFFF:
        raise ValueError(
            f"a message of {len(frame)} bytes needs {count} chunks of {max_bytes} bytes: over 65535"
        )
    return [
        _HEAD.pack(MAGIC, VERSION, number, k, count, len(frame)) + frame[k * room : (k + 1) * room]
        for k in range(count)
    ]


def wire_bytes(frame_bytes: int, max_bytes: int) -> int:
    """Bytes a frame of ``frame_bytes`` takes as chunks of at most ``max_bytes``."""
    return frame_bytes + HEAD_BYTES * max(1, -(-frame_bytes // (max_bytes - HEAD_BYTES)))


class Reassembler:
    """Chunks from senders in, whole messages out; ``max_bytes`` bounds a message."""

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self.dropped = 0  #: chunks refused (malformed, inconsistent, too big)
        self._open: dict[str, OrderedDict] = {}  # sender -> number -> (count, length, parts)

    def add(self, sender: str, chunk: bytes) -> bytes | None:
        """The whole message this chunk completes, or None."""
        if len(chunk) < HEAD_BYTES:
            self.dropped += 1
            return None
        magic, version, number, index, count, length = _HEAD.unpack_from(chunk)
        if (magic, version) != (MAGIC, VERSION) or not index < count or length > self.max_bytes:
            self.dropped += 1
            return None
        pending = self._open.setdefault(sender, OrderedDict())
        count0, length0, parts = pending.get(number, (count, length, {}))
        if (count0, length0) != (count, length):
            self.dropped += 1
            return None
        parts[index] = chunk[HEAD_BYTES:]
        pending[number] = (count, length, parts)
        if len(parts) < count:
            while len(pending) > KEEP:
                pending.popitem(last=False)
            return None
        del pending[number]
        frame = b"".join(parts[k] for k in range(count))
        if len(frame) != length:
            self.dropped += 1
            return None
        return frame
