"""No "Exception ignored" at any exit: every process pool doorlab starts is ended with its
manager thread joined (``doorlab.runtime.interrupts.end_pool``).

CPython's exit hook for process pools (``concurrent.futures.process._python_exit``) wakes
every pool's manager thread through a pipe, without the pool's lock; a manager thread still
running at exit may close that pipe meanwhile, and on a busy machine ``doorlab run`` printed
"Exception ignored ... concurrent/futures/process.py ... OSError: [Errno 9] Bad file
descriptor". The race needs the thread alive at exit; these tests check that none is, on
each way a pool ends (the plot worker after its plots or at once, the local executor stopped).
"""

from __future__ import annotations

import concurrent.futures.process
import signal
import subprocess
import sys
import threading
import time

import pytest

from doorlab.outputs import runs
from doorlab.runtime.executor import LocalExecutor


def _manager_threads() -> list[threading.Thread]:
    cls = concurrent.futures.process._ExecutorManagerThread
    return [t for t in threading.enumerate() if isinstance(t, cls) and t.is_alive()]


@pytest.mark.parametrize("at_once", [False, True], ids=["after_plots", "at_once"])
def test_the_plot_worker_leaves_no_pool_thread_behind(at_once):
    assert not _manager_threads()
    worker = runs._plot_worker()
    worker.submit(int).result(timeout=300)  # the worker is up (it imported the plots)
    if at_once:
        worker.submit(time.sleep, 60)  # busy: stopped without waiting
    start = time.monotonic()
    runs._stop_plot_worker(worker, at_once=at_once)
    assert not _manager_threads()
    assert time.monotonic() - start < 30.0


def test_a_stopped_local_executor_leaves_no_pool_thread_behind():
    executor = LocalExecutor(1)
    executor.submit(int).result(timeout=300)
    executor.submit(time.sleep, 60)
    executor.stop()
    assert not _manager_threads()


_IN_A_FINALIZER = r"""
import concurrent.futures, os, signal, sys, time, weakref
from doorlab.runtime.interrupts import completed, install_signal_handlers

install_signal_handlers()


class Thing:
    def __del__(self):  # where the garbage collector drops an exception: foreseen
        os.kill(os.getpid(), {signum})


def callback(_):  # a weakref callback: dropped as well, but not on the list
    os.kill(os.getpid(), {signum})


thing = Thing()
if {weakref_callback}:
    ref = weakref.ref(thing, callback)
    thing.__class__ = type("Plain", (), {{}})  # no __del__ any more
start = time.monotonic()
try:
    del thing
    print("went on", flush=True)
    if {weakref_callback}:
        for _ in completed([concurrent.futures.Future()], poll_s=0.05):  # never done
            pass
    else:
        time.sleep(60)
except KeyboardInterrupt as e:
    print(type(e).__name__, getattr(e, "signum", 2), f"{{time.monotonic() - start:.3f}}")
    sys.exit(0)
print("not raised")
sys.exit(1)
"""


@pytest.mark.parametrize("weakref_callback", [False, True], ids=["__del__", "weakref callback"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_in_a_finalizer_is_not_lost(signum, weakref_callback):
    """A Ctrl-C (or SIGTERM) that arrives while the garbage collector runs a finalizer, where
    Python drops the exception a handler raises ("Exception ignored ... KeyboardInterrupt", and
    ``doorlab report`` once went on to write its page): in a ``__del__`` or the import system's
    module-lock callback it is delivered again once the finalizer returned, silently; in any
    other weakref callback it is dropped, and the wait for the workers raises it again."""
    code = _IN_A_FINALIZER.format(signum=int(signum), weakref_callback=weakref_callback)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, (proc.stdout, proc.stderr)
    assert ("Exception ignored" in proc.stderr) == weakref_callback, proc.stderr
    went_on, raised = proc.stdout.splitlines()
    assert went_on == "went on"
    name, number, waited = raised.split()
    assert name == ("KeyboardInterrupt" if signum == signal.SIGINT else "Interrupted")
    assert int(number) == int(signum)
    assert float(waited) < 30.0  # ~0.01 s in fact; the defect is "never" (60 s, or forever)


_CTRL_C_WHILE_SPAWNING = r"""
import os, signal, threading, time
import multiprocessing.util as util
from doorlab.runtime.executor import LocalExecutor
from doorlab.runtime.interrupts import install_signal_handlers

install_signal_handlers()
threading.Thread(target=time.sleep, args=(60,), daemon=True).start()  # SIGINT not blocked
real = util.spawnv_passfds


def spawn_then_ctrl_c(path, args, passfds):
    pid = real(path, args, passfds)
    if any("spawn_main" in str(a) for a in args):  # a worker, before its parent writes to it
        os.kill(os.getpid(), signal.SIGINT)  # lands on the other thread: the main one blocks it
        time.sleep(0.1)  # Python runs the handler in the main thread meanwhile
    return pid


util.spawnv_passfds = spawn_then_ctrl_c
executor = LocalExecutor(1)
try:
    executor.submit(int)
    time.sleep(5)
    print("not raised", flush=True)
except KeyboardInterrupt:
    print("KeyboardInterrupt", flush=True)
    executor.stop()
"""


def test_ctrl_c_while_a_worker_is_spawned_is_raised_once_it_is_known():
    """Ctrl-C that lands on another thread while a worker is being started (the main thread's
    signal mask does not stop Python from running the handler there): raised once the worker
    is started and its pool knows it, which stops it; the worker prints nothing (before the
    fix it read a closed pipe and printed an EOFError traceback: CI, test_hangs)."""
    proc = subprocess.run(
        [sys.executable, "-c", _CTRL_C_WHILE_SPAWNING], capture_output=True, text=True, timeout=120
    )
    assert proc.stdout.strip() == "KeyboardInterrupt", (proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "Error" not in proc.stderr, proc.stderr
