"""Helper processes: more interpreters, one per extra core, that run numerics handed to them.

Why processes and not threads: a latent fit is thousands of small torch calls, and between
them the Python glue holds the interpreter, so two fitting threads of one process wait on
each other (two objects on two threads: 1.2x, not 2x; two processes side by side each keep
their serial speed: docs/experiments.md, "A shorter refinement"). A long-running process (a
server, an evaluation) starts its helpers once with :func:`start`; everything else keeps
:func:`helpers` empty and runs in-process.

A helper is ``python -m cnfmp.helper_processes FD``: it configures the process as
:func:`cnfmp.runtime.configure` does (one intra-op thread, so its kernels give the same bits as
the parent's), then answers messages on the socket FD, one at a time and in order. A message
names a handler, ``"module:function"``, that the helper imports on first use and calls with
the message's payload; the handler's module keeps whatever state it needs between calls (a
loaded model). A helper exits when the parent's end of the socket closes, so it never
outlives the process that started it.
"""

from __future__ import annotations

import atexit
import importlib
import os
import signal
import socket
import subprocess
import sys
import threading
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from multiprocessing.connection import Connection
from typing import Callable, TypeVar

T = TypeVar("T")

__all__ = ["HelperError", "HelperProcess", "default_count", "helpers", "share", "start", "stop"]


class HelperError(RuntimeError):
    """A helper process died or could not be reached; the work it held must run elsewhere."""


class _Failed:
    """What a helper sends back when its handler raised: the exception itself when it can be
    pickled, else its text."""

    def __init__(self, error: BaseException):
        self.error = error


class HelperProcess:
    """One helper interpreter and the thread of this process that talks to it.

    :meth:`submit` queues a message and returns a future: messages run in the order
    submitted, and the talking thread waits on the socket with the interpreter released, so
    the caller can do its own share of the work meanwhile."""

    def __init__(self):
        ours, theirs = socket.socketpair()
        package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ)
        # The helper must import this very cnfmp, even from a checkout that is not installed.
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [package_root, env.get("PYTHONPATH")]))
        self.process = subprocess.Popen(
            [sys.executable, "-m", "cnfmp.helper_processes", str(theirs.fileno())],
            pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=env)
        theirs.close()
        self._connection = Connection(ours.detach())
        self._talker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cnfmp-helper")
        self.broken: str | None = None

    def submit(self, handler: str, payload) -> Future:
        """Runs ``handler(payload)`` in the helper (handler: ``"module:function"``); the
        future's result is what it returned. The future raises what the handler raised (a
        :class:`HelperError` naming it when it cannot be pickled), or :class:`HelperError`
        when the helper is gone or closed."""
        try:
            return self._talker.submit(self._call, handler, payload)
        except RuntimeError as err:  # closed: the executor takes no more work
            raise HelperError(f"helper process {self.process.pid} is closed") from err

    def _call(self, handler: str, payload):
        if self.broken:
            raise HelperError(self.broken)
        try:
            self._connection.send((handler, payload))
            answer = self._connection.recv()
        except (EOFError, OSError) as err:
            code = self.process.poll()
            self.broken = (f"helper process {self.process.pid} is gone"
                           f"{f' (exit status {code})' if code is not None else ''}: {err or type(err).__name__}")
            raise HelperError(self.broken) from err
        if isinstance(answer, _Failed):
            if isinstance(answer.error, BaseException):
                raise answer.error
            raise HelperError(f"{handler} failed in helper process {self.process.pid}: {answer.error}")
        return answer

    def close(self) -> None:
        """Closes the socket (the helper then exits) and waits up to 5 s for it."""
        self.broken = self.broken or f"helper process {self.process.pid} is closed"
        self._talker.shutdown(wait=True)
        self._connection.close()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()


_HELPERS: list[HelperProcess] = []
_LOCK = threading.Lock()


def default_count() -> int:
    """Helpers that fill this process's cores: one fewer than ``CNFMP_INFERENCE_THREADS``, or
    than the cores the process may use."""
    cores = int(os.environ.get("CNFMP_INFERENCE_THREADS", 0)) or len(os.sched_getaffinity(0))
    return max(0, cores - 1)


def start(count: int | None = None, preload: tuple[str, ...] = ()) -> int:
    """Starts helpers until there are `count` (default :func:`default_count`); returns how
    many run. Idempotent. A new helper first imports the modules `preload` names (a few
    seconds for torch) on its own core, while the caller goes on."""
    wanted = default_count() if count is None else count
    if wanted < 0:
        raise ValueError(f"the number of helper processes must be >= 0, got {wanted}")
    with _LOCK:
        if wanted and not _HELPERS:
            atexit.register(stop)
        while len(_HELPERS) < wanted:
            helper = HelperProcess()
            if preload:
                helper.submit(f"{__name__}:_import_modules", tuple(preload))
            _HELPERS.append(helper)
        return len(_HELPERS)


def helpers() -> list[HelperProcess]:
    """The running helpers that still answer (empty unless :func:`start` was called)."""
    return [helper for helper in _HELPERS if not helper.broken]


def share(count: int, here: Callable[[int], T], there: Callable[["HelperProcess", int], T],
          helpers_to_use: list["HelperProcess"] | None = None) -> list[T]:
    """Runs jobs 0..count-1 on this thread (``here(j)``) and on the helpers (``there(helper,
    j)``, which submits job j to `helper` and waits for its answer), each taking the next
    job when it is free, so that all end together however their speeds differ; returns the
    answers in job order. A helper that fails (:class:`HelperError`) is reported on stderr
    and its job done here. `helpers_to_use`: default :func:`helpers`."""
    waiting = deque(range(count))
    answers: list = [None] * count
    lock = threading.Lock()

    def take() -> int | None:
        with lock:
            return waiting.popleft() if waiting else None

    def feed(helper: HelperProcess) -> None:
        while (j := take()) is not None:
            try:
                answers[j] = there(helper, j)
            except HelperError as err:
                print(f"cnfmp: {err}; doing its work in this process", file=sys.stderr)
                with lock:
                    waiting.appendleft(j)
                return

    feeders = [threading.Thread(target=feed, args=(helper,), name="cnfmp-helper-feed")
               for helper in (helpers() if helpers_to_use is None else helpers_to_use)]
    for feeder in feeders:
        feeder.start()
    while (j := take()) is not None:
        answers[j] = here(j)
    for feeder in feeders:
        feeder.join()
    while (j := take()) is not None:  # put back by a feeder that failed after our last take
        answers[j] = here(j)
    return answers


def stop() -> None:
    """Closes every helper (tests; a process that exits needs not: its helpers see the
    socket close and exit)."""
    with _LOCK:
        while _HELPERS:
            _HELPERS.pop().close()


def _import_modules(names: tuple[str, ...]) -> None:
    """A handler: imports the modules `names` (a helper's preload)."""
    for name in names:
        importlib.import_module(name)


def _serve(fd: int) -> None:
    """The helper's loop: answer each (handler, payload) message until the socket closes."""
    from cnfmp import runtime

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when the work ends
    runtime.configure()
    connection = Connection(fd)
    handlers = {}
    while True:
        try:
            handler, payload = connection.recv()
        except (EOFError, OSError):
            return
        try:
            function = handlers.get(handler)
            if function is None:
                module, name = handler.split(":")
                function = handlers[handler] = getattr(importlib.import_module(module), name)
            answer = function(payload)
        except Exception as err:  # noqa: BLE001 - every failure goes back to the caller
            answer = _Failed(err)
        try:
            connection.send(answer)
        except (EOFError, OSError):
            return
        except Exception as err:  # noqa: BLE001 - an answer that cannot be pickled
            connection.send(_Failed(f"{type(err).__name__}: {err}"))


if __name__ == "__main__":
    # Through the module's own name, so that what the helper pickles (a _Failed) is
    # cnfmp.helper_processes._Failed to the parent, not __main__._Failed.
    from cnfmp import helper_processes

    helper_processes._serve(int(sys.argv[1]))
