"""A bounded hand-off between the executor thread and the worker that keeps the newest items.

The subscription callback must return at once so the executor keeps serving
timers and other callbacks while a scan is being labelled (hundreds of ms on a
CPU). When scans arrive faster than they can be labelled, the *oldest* waiting
scan is dropped and counted: a MOS node must work on the newest scan, never
build a backlog whose latency grows without bound.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestQueue(Generic[T]):
    """Thread-safe queue of at most ``maxsize`` items; ``put`` on a full queue drops the oldest."""

    def __init__(self, maxsize: int = 1) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self._items: deque[T] = deque()
        self._maxsize = maxsize
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0
        self.put_count = 0

    def put(self, item: T) -> bool:
        """Enqueue ``item``; returns True if an older item had to be dropped to make room."""
        with self._cond:
            if self._closed:
                return False
            dropped = len(self._items) >= self._maxsize
            if dropped:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
            self._cond.notify()
            return dropped

    def get(self, timeout: float | None = None) -> T | None:
        """The oldest waiting item, or None after ``timeout`` seconds or once closed and empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._items or self._closed, timeout=timeout):
                return None
            return self._items.popleft() if self._items else None

    def close(self) -> None:
        """Wake every waiting ``get``; later puts are ignored, waiting items are discarded."""
        with self._cond:
            self._closed = True
            self._items.clear()
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
