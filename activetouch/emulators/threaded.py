"""The lifecycle the byte-level emulators share: `start()` opens the device's endpoint and runs
its `_loop` on a daemon thread until `stop()`, which joins the thread and closes the endpoint.
Also a context manager."""

from __future__ import annotations

import threading
from typing import Self


class ThreadedEmulator:
    thread_name = "emulator"
    _running = False
    _thread: threading.Thread | None = None

    def _open(self) -> None:
        """Before the thread starts: buses, clocks (subclasses)."""

    def _close(self) -> None:
        """After the thread has stopped: sockets, pty ends, buses (subclasses)."""

    def _loop(self) -> None:
        raise NotImplementedError

    def start(self) -> Self:
        self._open()
        self._running = True
        self._thread = threading.Thread(target=self._loop, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
