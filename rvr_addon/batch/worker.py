"""The worker side of the batch: one estimator per worker process, and its thread budget.

:class:`EstimatorPlugin` is a ``distributed`` worker plugin: registered once by the client, it
runs :meth:`setup` in every worker (also in workers that join or are restarted later), which
sets the threads each task may use and loads the estimator weights once. Tasks get the model
with :func:`worker_model`; outside a worker (or for other weights) it is loaded on the spot.
"""
from __future__ import annotations

import logging
from pathlib import Path

from distributed import WorkerPlugin

log = logging.getLogger(__name__)

PLUGIN_NAME = "rvr-estimator"


class EstimatorPlugin(WorkerPlugin):
    """Worker plugin: thread budget and the estimator, set up once per worker process.

    weights: estimator weights file, or None when the batch needs no network (external depth
    and ``--no-hdr``). task_threads: torch and OpenCV threads per task (1 = one core per
    task; a worker runs ``threads_per_worker`` tasks at once). loads counts the loads.
    """

    name = PLUGIN_NAME

    def __init__(self, weights: Path | None, task_threads: int = 1) -> None:
        self.weights = Path(weights) if weights is not None else None
        self.task_threads = int(task_threads)
        self.model = None
        self.loads = 0

    def setup(self, worker=None) -> None:
        """Set thread counts; load the weights (once per worker process)."""
        import cv2
        import torch

        torch.set_num_threads(self.task_threads)
        cv2.setNumThreads(self.task_threads)
        if self.weights is not None:
            from ..estimate.infer import load_estimator

            self.model = load_estimator(self.weights)
            self.loads += 1
            log.info("worker %s: loaded estimator %s (%s)", getattr(worker, "address", "?"), self.weights,
                     self.model.model_hash)

    def teardown(self, worker=None) -> None:
        """Drop the model."""
        self.model = None


def worker_model(weights: Path | None):
    """The estimator loaded for ``weights`` in this worker (its plugin's), else a fresh load.
    None when ``weights`` is None."""
    if weights is None:
        return None
    try:
        from distributed import get_worker

        plugin = get_worker().plugins.get(PLUGIN_NAME)
    except (ImportError, ValueError):
        plugin = None
    if plugin is not None and plugin.model is not None and plugin.weights == Path(weights):
        return plugin.model
    from ..estimate.infer import load_estimator

    return load_estimator(weights)


def worker_task_threads() -> int | None:
    """The thread budget of a task in this worker (its plugin's ``task_threads``, i.e. ``rvr batch
    --task-threads``), or None outside a batch worker."""
    try:
        from distributed import get_worker

        plugin = get_worker().plugins.get(PLUGIN_NAME)
    except (ImportError, ValueError):
        return None
    return getattr(plugin, "task_threads", None)


def loads_per_worker(client) -> dict[str, int]:
    """{worker address: number of estimator loads} of a running cluster (for tests and logs)."""
    def _loads(dask_worker) -> int:
        plugin = dask_worker.plugins.get(PLUGIN_NAME)
        return plugin.loads if plugin is not None else 0

    return client.run(_loads)
