"""A stage of a pass over a drive, run in a process of its own that works ahead while the caller's Python runs.

KISS-ICP's alignment and the rest of the numeric work hold the GIL, so on a 2-core machine a thread cannot overlap
them with the caller; a process can. :class:`Worker` starts a fresh interpreter (``python -c``, the caller's
``sys.path``) that builds a handler from a setup message (``SERVER(setup) -> handle``, named as ``module:function``)
and then answers each request with the list ``handle(request)`` returns, in order. Requests go out through a thread
that writes them to the process's stdin (:meth:`Worker.send` never waits for the process); answers come back on a
pipe of its own, so that nothing the process prints can garble them. Not :mod:`multiprocessing`: its children
import the caller's main script again (a user's script without a ``__main__`` guard would run twice).

An error in the process comes back as the MosError to raise (other exceptions as a :class:`WorkerError` naming
them); a process that dies (killed, out of memory, aborted) is a WorkerError with its exit code.
"""

from __future__ import annotations

import importlib
import os
import pickle
import queue
import signal
import subprocess
import sys
import threading
from typing import Any, Callable

from ros2_mos.core.errors import MosError, WorkerError

#: Seconds a stopping worker may take before it is killed.
CLOSE_WAIT_S = 5.0


class Worker:
    """One worker process: ``server`` ("package.module:function") builds its handler from ``setup``."""

    def __init__(self, server: str, setup: Any, name: str) -> None:
        self.name = name
        answers, answer_here = os.pipe()
        environment = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-c", "from ros2_mos.core.worker import serve; serve()", str(answer_here), server,
                 name], stdin=subprocess.PIPE, pass_fds=(answer_here,), env=environment)
        finally:
            os.close(answer_here)
        self._answers = os.fdopen(answers, "rb")
        self._outbox: queue.Queue[Any] = queue.Queue()
        self._feeder = threading.Thread(target=self._feed, name=f"{name} feeder", daemon=True)
        self._feeder.start()
        self._outbox.put(setup)

    def send(self, request: Any) -> None:
        """Queue ``request`` for the process; returns at once."""
        self._outbox.put(request)

    def receive(self) -> Any:
        """The process's next answer; raises its error, or a WorkerError where it ended."""
        try:
            answer = pickle.load(self._answers)
        except (EOFError, pickle.UnpicklingError):
            raise WorkerError(f"the {self.name} process ended without its result (exit code "
                              f"{self._process.wait()})") from None
        if isinstance(answer, BaseException):
            raise answer
        return answer

    @property
    def returncode(self) -> int | None:
        """The process's exit code; None while it runs."""
        return self._process.poll()

    def close(self, kill: bool = False) -> None:
        """Stop the process: after the requests sent so far, or with ``kill`` at once (its answers are not needed:
        an error, Ctrl-C)."""
        if kill:
            self._process.kill()
        self._outbox.put(None)
        self._feeder.join(CLOSE_WAIT_S)
        try:
            self._process.wait(CLOSE_WAIT_S)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._answers.close()

    def _feed(self) -> None:
        """The feeder thread: the requests to the process's stdin, in order; closes it at the end."""
        stdin = self._process.stdin
        while (request := self._outbox.get()) is not None:
            try:
                pickle.dump(request, stdin, protocol=pickle.HIGHEST_PROTOCOL)
                stdin.flush()
            except OSError:  # the process ended (a broken pipe): receive() says so
                break
        try:
            stdin.close()
        except OSError:
            pass


def serve() -> None:
    """The worker process's main: ``python -c ... ANSWER_FD module:function NAME``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the caller, which stops this process
    answers = os.fdopen(int(sys.argv[1]), "wb")
    name = sys.argv[3]
    requests = sys.stdin.buffer

    def answer(message: Any) -> None:
        pickle.dump(message, answers, protocol=pickle.HIGHEST_PROTOCOL)
        answers.flush()

    served = 0
    try:
        module, function = sys.argv[2].split(":")
        server: Callable[[Any], Callable[[Any], list[Any]]] = getattr(importlib.import_module(module), function)
        handle = server(pickle.load(requests))
        while True:
            try:
                request = pickle.load(requests)
            except EOFError:
                return
            for message in handle(request):
                answer(message)
            served += 1
    except MosError as exc:
        answer(exc)
    except Exception as exc:  # noqa: BLE001 - the caller raises it, in one line
        answer(WorkerError(f"{name} failed at request {served}: {type(exc).__name__}"
                           f"{f': {exc}' if str(exc) else ''}"))
