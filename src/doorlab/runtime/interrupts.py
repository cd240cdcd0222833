"""How doorlab's processes leave on a signal, so that every way out cleans up.

In the ``doorlab`` process (:func:`install_signal_handlers`), Ctrl-C raises
KeyboardInterrupt and SIGTERM/SIGHUP raise :class:`doorlab.errors.Interrupted`, so one
``except``/``finally`` path removes staging folders and stops workers. Two places must not be
cut short by that exception: :func:`deferred_signals` holds a signal back over a few steps
that must happen together (swapping an output folder into place, removing a staging folder)
and raises it right after.

Worker processes (the plot worker, the report's and the sweep's local workers) are spawned
with SIGINT and SIGHUP blocked (:func:`spawning_workers`): Ctrl-C in a terminal reaches the
whole process group, and it is the parent's to handle (it stops its workers), so a worker
never prints a KeyboardInterrupt traceback. :func:`worker_signals` (their initializer) keeps SIGINT
ignored and leaves SIGTERM/SIGHUP to end them at once, silently: a worker writes only into
its parent's staging folder, which the parent removes after :func:`stop_processes`.

Python runs a signal's handler at the next bytecode boundary, wherever that is: in a weakref
callback or a ``__del__`` (the import system's module-lock callbacks run during garbage
collection), the exception it raises is printed as "Exception ignored" and dropped, and the
Ctrl-C is lost. So the handlers raise nothing there and deliver the signal again a moment
later (:func:`_drops_exceptions`); they also remember it, and the loops that wait for workers
(:func:`completed`) raise it again, for a place no list of such frames foresaw.
"""

from __future__ import annotations

import concurrent.futures
import os
import signal
import threading
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

from doorlab.errors import Interrupted

INTERRUPTS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals doorlab turns into an exception (and its workers into a quiet exit)."""


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def deferred_signals() -> Iterator[None]:
    """Holds Ctrl-C, SIGTERM and SIGHUP back for the ``with`` block; raises the first one
    that arrived right after it, through the handler that was installed (main thread only;
    elsewhere signals are not delivered to Python anyway)."""
    if not _main_thread():
        yield
        return
    pending: list[int] = []

    def remember(signum: int, frame) -> None:
        pending.append(signum)

    previous = {signum: signal.signal(signum, remember) for signum in INTERRUPTS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if pending:
            signum = pending[0]
            handler = previous[signum]
            if callable(handler):
                handler(signum, None)  # raises KeyboardInterrupt or Interrupted
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


@contextmanager
def ignoring_signals() -> Iterator[None]:
    """Ignores Ctrl-C, SIGTERM and SIGHUP for the block (the last clean-up at exit)."""
    if not _main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in INTERRUPTS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


_BORN_BLOCKED = {signal.SIGINT, signal.SIGHUP}
"""Signals a worker is born with blocked (see :func:`spawning_workers`)."""


@contextmanager
def spawning_workers() -> Iterator[None]:
    """Wrap what creates a process pool or starts its workers.

    The workers are born with SIGINT and SIGHUP blocked (a thread's signal mask survives fork
    and exec) until :func:`worker_signals` handles them: Ctrl-C and a closed terminal reach
    the whole process group, and both are this process's to handle. multiprocessing's
    resource tracker, started here if it is not running, keeps them blocked for good (it
    already ignores SIGINT and SIGTERM; a hang-up would kill it and leave its parent
    warning).

    The mask is the calling thread's: a signal sent to the process can still land on another
    of its threads (a pool's manager thread, a progress bar's), and Python then runs its
    handler in the main thread all the same. Raised there, between a worker's start and the
    preparation data its parent writes to it, the worker was left reading a closed pipe and
    printed an ``EOFError`` traceback. So the block also holds the handlers back
    (:func:`deferred_signals`): a signal that arrives meanwhile is raised once the workers
    are started and known to their pool, which then stops them.
    """
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        yield
        return
    from multiprocessing import resource_tracker

    with deferred_signals():
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, _BORN_BLOCKED)
        try:
            resource_tracker.ensure_running()
            # ensure_running unblocks SIGINT and SIGTERM after starting the tracker: again.
            signal.pthread_sigmask(signal.SIG_BLOCK, _BORN_BLOCKED)
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def worker_signals() -> None:
    """A worker process's signal handling (its pool's initializer): Ctrl-C ignored (the
    parent's to handle); SIGTERM and SIGHUP end it at once, silently, as by default (a
    worker leaves nothing to clean up: what it writes lies in its parent's staging folder,
    which the parent removes once the worker is gone, :func:`stop_processes`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _BORN_BLOCKED)


def stop_processes(processes, *, grace_s: float = 2.0) -> None:
    """Terminates worker processes, waits ``grace_s`` for their clean-up, then kills the rest.

    Args:
        processes: ``multiprocessing.Process`` objects (a pool's workers).
        grace_s: How long a worker may take to unwind its task [s].
    """
    processes = [p for p in processes if p.is_alive()]
    for process in processes:
        try:
            process.terminate()
        except (OSError, ValueError):  # already gone, or closed
            pass
    for process in processes:
        process.join(timeout=grace_s)
    for process in processes:
        if process.is_alive():
            try:
                os.kill(process.pid, signal.SIGKILL)
            except OSError:
                pass
            process.join(timeout=grace_s)


POOL_JOIN_S = 10.0
"""How long :func:`end_pool` waits for a pool's manager thread [s] (it sends the workers
their stop and joins them: a fraction of a second)."""


def end_pool(pool, *, at_once: bool = False, join_s: float = POOL_JOIN_S) -> None:
    """Ends a ``ProcessPoolExecutor``: cancels its pending tasks, stops its workers
    (``at_once``: :func:`stop_processes`, without waiting for their tasks; else they finish
    the task in hand) and waits for its manager thread.

    That last wait is the point: ``shutdown(wait=False)`` leaves the manager thread closing
    the pool's wake-up pipe while the interpreter exits, and CPython's exit hook
    (``concurrent.futures.process._python_exit``) writes to that pipe without the pool's
    lock: on a busy machine the two meet and Python prints "Exception ignored ...
    OSError: [Errno 9] Bad file descriptor" at exit. Once the thread is gone the pipe is
    closed and marked so, and the hook leaves it alone.
    """
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    if at_once:
        stop_processes(processes)
    if manager is not None and manager.is_alive():
        manager.join(join_s)


_received: list[int] = []
"""The signals :func:`install_signal_handlers`' handlers received, in the order they came."""


def _exception(signum: int) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == signal.SIGINT else Interrupted(signum)


REDELIVER_S = 0.01
"""How long after a signal that arrived in a finalizer it is delivered again [s]."""


def _drops_exceptions(frame) -> bool:
    """Whether an exception raised in ``frame`` would be dropped on its way up: the frame or
    a caller is an object's ``__del__`` or a module-lock callback of the import system (both
    run from the garbage collector, which prints "Exception ignored" and goes on)."""
    while frame is not None:
        code = frame.f_code
        if code.co_name == "__del__" or (
            code.co_name == "cb" and code.co_filename.startswith("<frozen importlib")
        ):
            return True
        frame = frame.f_back
    return False


def _deliver_again(signum: int) -> None:
    """Sends ``signum`` to the main thread again in :data:`REDELIVER_S`, from a helper thread
    (by then the finalizer it arrived in has returned: it runs for microseconds)."""
    main = threading.main_thread().ident

    def send() -> None:
        time.sleep(REDELIVER_S)
        signal.pthread_kill(main, signum)

    threading.Thread(target=send, name="doorlab-signal", daemon=True).start()


def _raise_interrupted(signum: int, frame) -> None:
    _received.append(signum)
    if _drops_exceptions(frame):
        _deliver_again(signum)
        return
    raise _exception(signum)


def install_signal_handlers() -> None:
    """Ctrl-C raises KeyboardInterrupt; SIGTERM and SIGHUP raise
    :class:`doorlab.errors.Interrupted` (a KeyboardInterrupt), so they leave through the same
    clean-up (main thread only). Each handler remembers its signal for :func:`completed`."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in INTERRUPTS:
        signal.signal(signum, _raise_interrupted)


def raise_if_interrupted() -> None:
    """Raises the first signal the handlers received, again: for a loop that must not go on
    after a Ctrl-C or SIGTERM whose exception Python may have dropped (see the module's
    docstring). A no-op unless :func:`install_signal_handlers` ran and a signal came."""
    if _received:
        raise _exception(_received[0])


POLL_S = 0.2
"""How often :func:`completed` looks for a signal whose exception was dropped [s]."""


def completed(
    futures: Iterable[concurrent.futures.Future], *, poll_s: float = POLL_S
) -> Iterator[concurrent.futures.Future]:
    """``concurrent.futures.as_completed`` that raises a received signal within ``poll_s``
    (:func:`raise_if_interrupted`) even if its exception was dropped where it was delivered.

    Args:
        futures: The futures to wait for.
        poll_s: The longest wait between two looks at the received signals [s].
    """
    pending = set(futures)
    while pending:
        raise_if_interrupted()
        done, pending = concurrent.futures.wait(
            pending, timeout=poll_s, return_when=concurrent.futures.FIRST_COMPLETED
        )
        for future in done:
            yield future
            raise_if_interrupted()
