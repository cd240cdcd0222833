"""The suite's pytest-xdist scheduler: ``--dist loadfile`` with the real-time files in bins
(tests/file_order.py), which survives a worker that dies.

pytest-xdist's own loadfile scheduler (``LoadScopeScheduling``, 3.8) handles a dead worker
badly (issue 45: the quick tier on Drake 1.58, where a worker crashed, ended in ``KeyError:
<WorkerController gw5>``; here it hangs): it puts the dead worker's whole workload back in
the queue, the files it had finished and the test that crashed included, so the crash runs
again on the next worker and kills it too, and finished files are handed out with nothing
to run. :class:`RealtimeBins` instead

- reports the test that was running as the crash (xdist's "worker 'gwN' crashed while running
  ..."), once: it is not run again;
- gives the rest of the dead worker's unfinished files to the others, first in the queue
  (a file's module fixtures then run again on its new worker);
- keeps every result already reported, and ignores a late report of a removed worker or a
  replacement worker whose collection it never registered (it is shut down);
- gives a replacement worker enough to run: xdist's handed it one file and no word that
  nothing more was coming, and it waited on that file's last test forever (a worker runs a
  test only once it knows the next).
"""

from __future__ import annotations

from collections.abc import Callable

from xdist.scheduler import LoadFileScheduling


class RealtimeBins(LoadFileScheduling):
    """``--dist loadfile``, a file per unit of work except the real-time files, which go in
    the bins ``bins(number of workers)`` returns ({file name: bin name}), a bin per unit.

    Args:
        config, log: pytest-xdist's (``pytest_xdist_make_scheduler``).
        bins: Called once, when every worker's collection is in.
    """

    def __init__(self, config, log, bins: Callable[[int], dict[str, str]]):
        super().__init__(config, log)
        self._make_bins = bins
        self._bins: dict[str, str] | None = None

    def _split_scope(self, nodeid: str) -> str:
        scope = super()._split_scope(nodeid)
        if self._bins is None:  # called once every worker's collection is in
            self._bins = self._make_bins(self.numnodes)
        return self._bins.get(scope.rsplit("/", 1)[-1], scope)

    def remove_node(self, node) -> str | None:
        """A worker that finished, or died: returns the test it was running when it died
        (None: it had nothing pending), which xdist reports as failed; its other unfinished
        tests go back to the front of the queue (see the module)."""
        workload = self.assigned_work.pop(node, None)
        if not workload or not self._pending_of(workload):
            return None
        crashed = next(
            nodeid for unit in workload.values() for nodeid, done in unit.items() if not done
        )
        workload[self._split_scope(crashed)][crashed] = True  # reported, never run again
        unfinished = [(s, unit) for s, unit in workload.items() if not all(unit.values())]
        for scope, unit in reversed(unfinished):
            self.workqueue[scope] = unit
            self.workqueue.move_to_end(scope, last=False)
        for other in list(self.assigned_work):
            self._reschedule(other)
        return crashed

    def mark_test_complete(self, node, item_index: int, duration: float = 0) -> None:
        if node in self.assigned_work:  # not a late report of a removed worker
            super().mark_test_complete(node, item_index, duration)

    def _reschedule(self, node) -> None:
        """Tops ``node`` up to more than two pending tests while there is work, and tells it
        that no more is coming once the queue is empty (a worker runs its last test only then:
        pytest needs the next one for the teardowns). xdist's gives one unit per call, which
        left a replacement worker waiting on its one test forever."""
        if node.shutting_down:
            return
        if node not in self.registered_collections:  # a replacement that collected otherwise
            node.shutdown()
            return
        try:
            while self.workqueue and self._pending_of(self.assigned_work[node]) <= 2:
                self._assign_work_unit(node)
        except OSError:  # it died and its death is not handled yet: remove_node requeues
            return
        if not self.workqueue:
            node.shutdown()
