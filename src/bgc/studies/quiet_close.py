"""A worker plugin for bgc's own local Dask clusters: no traceback on the user's terminal
from a connection that a closing worker broke itself.

A worker closes its own connection pool as it shuts down. A heartbeat in flight at that moment
fails with CommClosedError, and distributed logs it with its traceback ("Failed to communicate
with scheduler during heartbeat"). At the end of a sweep that is a race inside distributed's
shutdown, not an error of the sweep. The filter drops exactly those records: an OSError's
(CommClosedError is one) on the ``distributed.worker`` logger while that worker is closing or
closed. Every record of a running worker passes untouched.

Imported only where a local cluster starts (it imports distributed).
"""
from __future__ import annotations

import logging

from distributed import WorkerPlugin

CLOSING = frozenset({"closing", "closed", "closing_gracefully", "failed"})


class ClosingCommFilter(logging.Filter):
    """Drops a broken-connection record logged while ``worker`` is closing."""

    def __init__(self, worker):
        super().__init__()
        self.worker = worker

    def filter(self, record):
        status = getattr(getattr(self.worker, "status", None), "name", "running")
        exc = record.exc_info[1] if record.exc_info else None
        return not (status in CLOSING and isinstance(exc, OSError))


class QuietWorkerClose(WorkerPlugin):
    """Installs :class:`ClosingCommFilter` on each worker's logger, and removes it again."""

    def setup(self, worker):
        self._filter = ClosingCommFilter(worker)
        logging.getLogger("distributed.worker").addFilter(self._filter)

    def teardown(self, worker):
        logging.getLogger("distributed.worker").removeFilter(self._filter)
