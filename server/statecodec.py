"""Engine state as stored in ``sessions.engine_state``: a checkpoint every few batches, or a complete state.

Two stored forms:

- a *checkpoint* (:func:`pack_checkpoint`, written by batch uploads): ``PNC1``, the number of batches it holds
  (little-endian uint64: the state after batches ``0 .. n - 1``) and the engine's own bytes, uncompressed. An
  upload writes one every ``Settings.state_every`` batches (``PEDNAV_STATE_EVERY``), not after every batch: the
  raw batches are stored durably with every upload before it is answered, and the engine is chunk invariant, so
  the last checkpoint plus the stored batches after it (:func:`server.ingest.replay_engine`) is exactly the state
  after the last batch. Uncompressed: zlib level 1 halves the bytes but cost more CPU than the database write it
  saved (``pednav bench engine``, docs/deployment.md).
- a *complete* state (:func:`pack_state`, written at session start and close, by re-processing and by the older
  servers that wrote after every batch): ``PNZ1`` and the zlib-compressed engine bytes, or the plain engine bytes
  from before compression. It holds every batch the session has (``next_seq``); an upload that meets one writes a
  checkpoint (the old form is migrated on the next batch).
"""

from __future__ import annotations

import struct
import zlib

__all__ = ["held_batches", "pack_checkpoint", "pack_state", "unpack_checkpoint", "unpack_state"]

_ZHEAD = b"PNZ1"  # pednav state, zlib-compressed engine bytes (complete)
_CHEAD = b"PNC1"  # pednav checkpoint: uint64 batch count, engine bytes
_N = struct.Struct("<Q")


def pack_state(state: bytes) -> bytes:
    """Stored form of a complete ``Engine.to_bytes()`` output (deterministic: equal states give equal blobs)."""
    return _ZHEAD + zlib.compress(state, 1)


def pack_checkpoint(state: bytes, n_batches: int) -> bytes:
    """Stored form of the engine state after the session's first ``n_batches`` batches."""
    return _CHEAD + _N.pack(int(n_batches)) + state


def unpack_checkpoint(blob: bytes) -> tuple[bytes, int | None]:
    """``(engine bytes, batches they hold)``; None for a complete state (it holds all the session's batches)."""
    if blob[:4] == _CHEAD:
        return bytes(blob[12:]), int(_N.unpack_from(blob, 4)[0])
    if blob[:4] == _ZHEAD:
        return zlib.decompress(blob[4:]), None
    return bytes(blob), None


def held_batches(blob: bytes) -> int | None:
    """The batches a checkpoint holds (None: a complete state), without decoding the engine bytes."""
    return int(_N.unpack_from(blob, 4)[0]) if blob[:4] == _CHEAD else None


def unpack_state(blob: bytes) -> bytes:
    """The engine's bytes of a stored blob (any form; a checkpoint's batches after it are not in them)."""
    return unpack_checkpoint(blob)[0]
