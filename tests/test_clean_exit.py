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
