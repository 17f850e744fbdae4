"""Rows appended at the end and dropped at the front of arrays that share their first axis (the streaming
buffers of the ZUPT-KF, its clipping repair and the gait field), in preallocated storage grown by doubling: a
batch writes its rows in place instead of re-allocating every row held (a concatenation per batch)."""

from __future__ import annotations

import numpy as np

__all__ = ["RowBuffer"]

_MIN_CAPACITY = 256  # rows


class RowBuffer:
    """Rows ``lo .. hi - 1`` of the arrays :attr:`storage` (one or more, same first axis).

    Parameters
    ----------
    *arrays : ndarray
        The initial rows (they become the storage: not copied).

    Attributes
    ----------
    storage : tuple of ndarray
        The preallocated arrays; compiled code may write rows ``hi ..`` of them after :meth:`reserve` and then
        set ``hi`` (and drop rows by raising ``lo``).
    lo, hi : int
        The rows held.
    """

    __slots__ = ("storage", "lo", "hi")

    def __init__(self, *arrays: np.ndarray) -> None:
        self.storage = arrays
        self.lo, self.hi = 0, arrays[0].shape[0]

    def __len__(self) -> int:
        return self.hi - self.lo

    def views(self) -> tuple[np.ndarray, ...]:
        """The rows held, one view per array (valid until the next :meth:`reserve` / :meth:`grow`)."""
        lo, hi = self.lo, self.hi
        return tuple([a[lo:hi] for a in self.storage])

    def reserve(self, k: int) -> None:
        """Room for ``k`` more rows after ``hi``: the held rows move to the front of the storage, or to a new
        storage of twice the rows needed when the current one is less than that."""
        if self.hi + k <= self.storage[0].shape[0]:
            return
        lo, hi = self.lo, self.hi
        n = hi - lo
        if 2 * (n + k) > self.storage[0].shape[0]:
            cap = max(2 * (n + k), _MIN_CAPACITY)
            new = tuple(np.empty((cap,) + a.shape[1:], dtype=a.dtype) for a in self.storage)
            for a, b in zip(new, self.storage):
                a[:n] = b[lo:hi]
            self.storage = new
        else:
            for a in self.storage:
                a[:n] = a[lo:hi]  # (NumPy copies through a temporary itself where the ranges overlap)
        self.lo, self.hi = 0, n

    def view(self, i: int = 0) -> np.ndarray:
        """The rows held of the ``i``-th array (a view, valid until the next :meth:`reserve` / :meth:`grow`)."""
        return self.storage[i][self.lo:self.hi]

    def add(self, k: int) -> None:
        """``k`` new rows after the held ones (uninitialised), for a caller that fills them through :meth:`view`
        (:meth:`grow` without its views)."""
        self.reserve(k)
        self.hi += k

    def grow(self, k: int) -> tuple[np.ndarray, ...]:
        """``k`` new rows after the held ones (uninitialised), one view per array, for the caller to fill."""
        self.add(k)
        hi = self.hi - k
        return tuple([a[hi:hi + k] for a in self.storage])

    def extend(self, *rows: np.ndarray) -> None:
        """Append ``rows`` (one array per storage array, same number of rows)."""
        for a, v in zip(self.grow(rows[0].shape[0]), rows):
            a[...] = v

    def drop(self, n: int) -> None:
        """Forget the first ``n`` rows held."""
        self.lo += n

    def clear(self) -> None:
        """Forget every row (the storage stays for the next ones)."""
        self.lo = self.hi = 0
