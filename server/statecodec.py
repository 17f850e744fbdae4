"""Engine state as stored in ``sessions.engine_state``: the engine's own bytes, zlib-compressed.

The server persists a session's engine state after every accepted batch, so its size is written (and sent
between processes) 200 times a second under the load target. zlib level 1 roughly halves it (a 1-min walk:
31.7 KB -> 18.0 KB) for about 0.2-0.27 ms of CPU, spent in the server's upload thread without the GIL. Blobs written before compression (they start with
the engine codec's own header) are read as they are.
"""

from __future__ import annotations

import zlib

__all__ = ["pack_state", "unpack_state"]

_ZHEAD = b"PNZ1"  # pednav state, zlib-compressed engine bytes


def pack_state(state: bytes) -> bytes:
    """Stored form of ``Engine.to_bytes()`` output (deterministic: equal states give equal blobs)."""
    return _ZHEAD + zlib.compress(state, 1)


def unpack_state(blob: bytes) -> bytes:
    """The engine's bytes back from a stored blob (compressed or, from older rows, plain)."""
    if blob[:4] == _ZHEAD:
        return zlib.decompress(blob[4:])
    return blob
