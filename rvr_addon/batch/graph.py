"""The client side of ``rvr batch``: cluster, task graph, progress bar, results.

Per clip the graph is (``k`` over the chunks of :func:`.chunks.chunk_ranges`)::

    probe -> estimate[k] -> merge_estimates -> stabilize[k] -> merge_stabilized
          -> laaf_measure[k] -> autofocus -> render[k] -> finalize

Probes are submitted first; when one returns, the rest of its clip's graph is submitted
(its frame count decides the chunks), so a clip that cannot be read fails alone at its
probe and every other clip goes on. A failing task fails its clip's later tasks with the
same error, which the finalize future reports. A worker that dies (killed, out of memory)
loses its running tasks; the scheduler runs them again elsewhere (up to dask's
``distributed.scheduler.allowed-failures`` times); ``retries`` adds retries on exceptions.
Earlier clips have priority, so clips finish one after the other rather than all at the end.
"""
from __future__ import annotations

import logging
import os
import sys
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from ..errors import InputError
from . import stages
from .chunks import chunk_ranges, estimate_ranges
from .inputs import clip_names, path_id
from .report import BatchReport, ClipOutcome
from .settings import BATCH_DIR, FORMATS, BatchSettings, ClipPlan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClusterSettings:
    """Where the tasks run. scheduler: address of an existing cluster (``tcp://HOST:PORT``;
    its workers must see the same paths and have rvr installed), or None for an embedded
    LocalCluster of ``workers`` processes (default: one per CPU core) with
    ``threads_per_worker`` task threads each. task_threads: torch/OpenCV threads per task.
    dashboard: serve Dask's dashboard when bokeh is installed."""

    scheduler: str | None = None
    workers: int | None = None
    threads_per_worker: int = 1
    task_threads: int = 1
    dashboard: bool = True

    def check(self) -> None:
        """Raise InputError naming the setting that is out of range."""
        if self.workers is not None and self.workers < 1:
            raise InputError(f"--workers must be >= 1, got {self.workers}")
        if self.threads_per_worker < 1 or self.task_threads < 1:
            raise InputError(f"--threads-per-worker and --task-threads must be >= 1, got {self.threads_per_worker} "
                             f"and {self.task_threads}")
        if self.scheduler is not None and "://" not in self.scheduler:
            raise InputError(f"--scheduler {self.scheduler!r} is not an address; give tcp://HOST:PORT")


def check_settings(settings: BatchSettings) -> None:
    """Raise InputError naming the setting at fault."""
    if settings.format not in FORMATS:
        raise InputError(f"--format {settings.format!r} is not known; use one of {', '.join(FORMATS)}")
    if settings.chunk_frames < 0:
        raise InputError(f"--chunk-frames must be >= 0 (0 = whole clips), got {settings.chunk_frames}")
    if settings.no_hdr and settings.depth_root is None:
        raise InputError("--no-hdr needs --depth-root: without external depth the network estimates D (and E)")
    if settings.depth_root is not None and not settings.depth_root.is_dir():
        raise InputError(f"--depth-root '{settings.depth_root}' is not a folder; give the folder holding one "
                         "sub-folder of disparity maps per clip, named after the clip")
    if settings.retries < 0:
        raise InputError(f"--retries must be >= 0, got {settings.retries}")
    from ..depth.system import METHODS, plan_depth

    if settings.depth_method not in METHODS:
        raise InputError(f"--depth-method {settings.depth_method!r}: choose one of {', '.join(METHODS)}")
    if settings.depth_root is not None and settings.depth_method not in ("auto", "external"):
        raise InputError(f"--depth-root gives the depth itself; it cannot be combined with --depth-method "
                         f"{settings.depth_method} (drop one of them)")
    if settings.depth_root is None and settings.depth_method == "external":
        raise InputError("--depth-method external needs --depth-root DIR (per-clip depth or disparity maps)")
    if settings.depth_method in ("people", "parallax") or settings.hfov_deg is not None:
        plan_depth(settings.depth_method, None, settings.hfov_deg)  # mediapipe missing, a bad --hfov: fail now


def resolve_weights(settings: BatchSettings) -> tuple[Path | None, str]:
    """(estimator weights file, the id of the networks for the fingerprint: the estimator's,
    and AF-Net's for preset learned). The weights are loaded once here, so a missing or corrupt
    file fails before any cluster starts, naming the file and the fix; the file is None when
    the batch needs no estimator (--depth-root with --no-hdr)."""
    from ..estimate.infer import default_weights, load_estimator

    afnet = afnet_id(settings)
    if settings.depth_root is not None and settings.no_hdr:
        return None, "none" + afnet
    path = Path(settings.weights) if settings.weights is not None else default_weights()
    model = load_estimator(path)
    return path.resolve(), model.model_hash + afnet


def afnet_id(settings: BatchSettings) -> str:
    """Id of the AF-Net weights preset learned uses (a hash of the file), for the fingerprint;
    "" for other presets. Loads them, so a missing or foreign file fails before any cluster
    starts, naming the file and the fix."""
    from ..afnet.infer import load_afnet

    if settings.preset != "learned":
        return ""
    return load_afnet(settings.afnet_weights)[1]["file_id"]


def plan_clips(clips: list[Path], settings: BatchSettings, fingerprint: str) -> list[ClipPlan]:
    """One :class:`ClipPlan` per clip: unique name, cache folder, work folder."""
    plans = []
    for i, (clip, name) in enumerate(zip(clips, clip_names(clips))):
        cache = settings.caches / f"{name}-{path_id(clip)}"
        work = settings.output / BATCH_DIR / "work" / f"{name}-{fingerprint[:8]}"
        plans.append(ClipPlan(i, Path(clip), name, cache, work))
    from ..io.paths import check_outputs

    inputs = [("clip", p.source) for p in plans]
    if settings.depth_root is not None:
        inputs += [("depth maps", settings.depth_root / p.name) for p in plans]
    check_outputs("batch", [(f"output of clip '{p.name}'", out) for p in plans
                            for out in (*p.output_paths(settings), p.cache, p.work)], inputs)
    return plans


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


@contextmanager
def open_client(cluster: ClusterSettings) -> Iterator[object]:
    """A ``distributed.Client``: to ``cluster.scheduler``, or to an embedded LocalCluster
    (closed on exit)."""
    from distributed import Client, LocalCluster

    cluster.check()
    if cluster.scheduler is not None:
        try:
            client = Client(cluster.scheduler, timeout="20s")
        except OSError as ex:
            raise InputError(f"cannot reach the Dask scheduler at {cluster.scheduler} ({ex}); start it "
                             "(`dask scheduler`, then `dask worker ADDRESS` on each machine) or drop --scheduler "
                             "for a local cluster") from ex
        with client:
            yield client
        return
    n = cluster.workers or os.cpu_count() or 1
    dashboard = ":8787" if cluster.dashboard and _has_bokeh() else None
    with LocalCluster(n_workers=n, threads_per_worker=cluster.threads_per_worker, processes=True,
                      dashboard_address=dashboard or ":0") as local, Client(local) as client:
        yield client


class BatchRunner:
    """Run a batch on a connected client (see the module docstring); :meth:`run` returns
    the :class:`BatchReport`."""

    def __init__(self, clips: list[Path], settings: BatchSettings, client, task_threads: int = 1,
                 progress: bool = True, weights: tuple[Path | None, str] | None = None) -> None:
        """weights: the result of :func:`resolve_weights` when the caller has it already."""
        check_settings(settings)
        self.settings = settings
        self.client = client
        self.progress = progress
        self.weights, weights_id = weights if weights is not None else resolve_weights(settings)
        self.fingerprint = settings.fingerprint(weights_id)
        self.plans = plan_clips(clips, settings, self.fingerprint)
        self.task_threads = task_threads
        self._token = uuid.uuid4().hex[:8]
        self._kind: dict[str, tuple[str, ClipPlan]] = {}
        self._clip_futures: dict[int, list] = {}
        self.outcomes: dict[int, ClipOutcome] = {}

    def _submit(self, fn, plan: ClipPlan, label: str, *args):
        key = f"rvr-{label}-{plan.name}-{plan.index}-{self._token}"
        fut = self.client.submit(fn, *args, key=key, priority=-plan.index, retries=self.settings.retries)
        self._clip_futures.setdefault(plan.index, []).append(fut)
        return fut

    def _submit_clip(self, plan: ClipPlan) -> list:
        s = self.settings
        ranges = chunk_ranges(plan.frames, s.chunk_frames)
        est = [self._submit(stages.estimate, plan, f"estimate-{a}", plan, s, self.weights, a, b)
               for a, b in estimate_ranges(plan.frames, s.chunk_frames, s.clip_wide_estimate)]
        merged = self._submit(stages.merge_estimates, plan, "merge-estimates", plan, est)
        stab = [self._submit(stages.stabilize, plan, f"stabilize-{a}", plan, s, a, b, merged) for a, b in ranges]
        stable = self._submit(stages.merge_stabilized, plan, "merge-stabilized", plan, stab)
        meas = [self._submit(stages.laaf_measure, plan, f"laaf-measure-{a}", plan, s, a, b, stable) for a, b in ranges]
        focus = self._submit(stages.autofocus, plan, "autofocus", plan, s, meas)
        ren = [self._submit(stages.render, plan, f"render-{a}", plan, s, a, b, focus) for a, b in ranges]
        tasks = est + [merged] + stab + [stable] + meas + [focus] + ren
        final = self._submit(stages.finalize, plan, "finalize", plan, s, self.fingerprint, ranges, tasks)
        futures = tasks + [final]
        for f in futures:
            self._kind[f.key] = ("final" if f is final else "task", plan)
        return futures

    def _register_plugin(self) -> None:
        from .worker import PLUGIN_NAME, EstimatorPlugin

        self.client.register_plugin(EstimatorPlugin(self.weights, self.task_threads), name=PLUGIN_NAME)

    def _outcome(self, plan: ClipPlan, status: str, **kw) -> None:
        self.outcomes[plan.index] = ClipOutcome(plan.source, plan.name, status, **kw)
        for f in self._clip_futures.pop(plan.index, []):
            self._kind.pop(f.key, None)
            f.release()

    def run(self) -> BatchReport:
        """Submit everything, follow it with a progress bar, return the report."""
        from distributed import as_completed
        from tqdm import tqdm

        self._register_plugin()
        workers = len(self.client.nthreads())
        t0 = time.perf_counter()
        probes = []
        for plan in self.plans:
            f = self._submit(stages.probe, plan, "probe", plan, self.settings, self.fingerprint)
            self._kind[f.key] = ("probe", plan)
            probes.append(f)
        bar = tqdm(total=len(probes), unit="task", desc="batch", disable=not self.progress, dynamic_ncols=True)
        ac = as_completed(probes)
        try:
            for fut in ac:
                bar.update(1)
                kind, plan = self._kind.get(fut.key, ("task", None))
                if kind == "probe":
                    self._probed(fut, plan, ac, bar)
                elif kind == "final":
                    if fut.status == "finished":
                        r = fut.result()
                        self._outcome(plan, "done", frames=r["frames"], outputs=r["outputs"],
                                      task_seconds={**r["task_seconds"], "finalize": round(r["seconds"], 4)},
                                      task_cpu_seconds={**r["task_cpu_seconds"],
                                                        "finalize": round(r["cpu_seconds"], 4)})
                    else:
                        self._outcome(plan, "failed", frames=plan.frames, reason=_reason(fut))
                bar.set_postfix_str(f"clips done {sum(o.status == 'done' for o in self.outcomes.values())}, "
                                    f"failed {sum(o.status == 'failed' for o in self.outcomes.values())}")
        except BaseException:
            self.client.cancel([f for fs in self._clip_futures.values() for f in fs])
            raise
        finally:
            bar.close()
        wall = time.perf_counter() - t0
        clips = [self.outcomes[p.index] for p in self.plans]
        return BatchReport(clips, wall, workers=workers, dashboard=_dashboard(self.client))

    def _probed(self, fut, plan: ClipPlan, ac, bar) -> None:
        if fut.status != "finished":
            self._outcome(plan, "failed", reason=_reason(fut))
            return
        r = fut.result()
        probed: ClipPlan = r["plan"]
        for f in self._clip_futures.pop(plan.index, []):
            self._kind.pop(f.key, None)
            f.release()
        if r["skip"]:
            self._outcome(probed, "skipped", frames=probed.frames,
                          outputs=[str(p) for p in probed.output_paths(self.settings)])
            return
        futures = self._submit_clip(probed)
        bar.total += len(futures)
        bar.refresh()
        ac.update(futures)


def _reason(fut) -> str:
    try:
        ex = fut.exception()
    except Exception as err:  # noqa: BLE001 - e.g. cancelled
        return f"{type(err).__name__}: {err}"
    text = str(ex) or type(ex).__name__
    return text if isinstance(ex, stages.StageError) else f"{type(ex).__name__}: {text}"


def _dashboard(client) -> str | None:
    if not _has_bokeh():
        return None
    try:
        return client.dashboard_link
    except Exception:  # noqa: BLE001 - no dashboard served
        return None


def run_batch(clips: list[Path], settings: BatchSettings, cluster: ClusterSettings | None = None, client=None,
              progress: bool = True) -> BatchReport:
    """Run ``rvr batch`` over ``clips``: on ``client`` if given, else on the cluster
    ``cluster`` describes (an embedded LocalCluster by default). Errors in the settings or
    the weights raise InputError before any cluster starts; a clip's failure is in the report."""
    cluster = cluster or ClusterSettings()
    cluster.check()
    check_settings(settings)
    weights = resolve_weights(settings)  # fail fast, before a cluster starts
    if client is not None:
        return BatchRunner(clips, settings, client, cluster.task_threads, progress, weights).run()
    t0 = time.perf_counter()
    with open_client(cluster) as c:
        startup = time.perf_counter() - t0
        link = _dashboard(c)
        if link and progress:
            print(f"rvr batch: dashboard at {link}", flush=True, file=sys.stderr)
        report = BatchRunner(clips, settings, c, cluster.task_threads, progress, weights).run()
    report.startup_s = startup
    return report
