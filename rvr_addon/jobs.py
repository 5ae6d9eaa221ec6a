"""The one shape of long work: :class:`Job`, driven by the CLI, Dask tasks and Blender's modal runner.

A job is built with its inputs checked (errors are raised by the constructor), then driven
``while job.step(): pass``. Between steps a driver reads ``progress`` (0..1) and ``text`` (what
the job is doing, or how it ended) and may call ``cancel()`` at any time: before the first
step, in the middle, or after the end (then it changes nothing). ``cancel()`` stops the job,
keeps what the job promises to keep (finished cache frames, a checkpoint) and removes its
partial outputs; it never touches what the user made. A job may also have ``abort()``, which
a driver calls instead of ``cancel()`` when a step failed (:func:`stop_job`).

No bpy, no heavy imports: the engine's jobs (``EstimateJob``, ``StabilizeJob``, ``RenderJob``,
``AutofocusJob``, the training runs) and the operators' jobs all satisfy this protocol.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

JOB_MEMBERS = ("step", "cancel", "progress", "text")
"""What every job has (``tests/engine/test_jobs.py`` checks each job class)."""


@runtime_checkable
class Job(Protocol):
    """A stepwise, cancellable piece of long work (see the module docstring)."""

    text: str
    """One line for a status bar: what the job does now, or how it ended."""

    @property
    def progress(self) -> float:
        """Fraction done, 0..1."""

    def step(self) -> bool:
        """Do the next piece of work; False once the job is done (then it does nothing more)."""

    def cancel(self) -> None:
        """Stop now (any time, also before the first step or after the end); idempotent."""


def missing_members(job: object) -> list[str]:
    """The members of :class:`Job` that ``job`` lacks (empty: it is a job)."""
    return [name for name in JOB_MEMBERS if not hasattr(job, name)]


def check_job(job: object) -> Job:
    """``job`` itself when it has every member of :class:`Job`; TypeError naming the missing ones."""
    missing = missing_members(job)
    if missing:
        raise TypeError(f"{type(job).__name__} is not a Job: it lacks {', '.join(missing)} "
                        "(see rvr_addon/jobs.py)")
    return job  # type: ignore[return-value]


def stop_job(job: Job, failed: bool = False) -> None:
    """Stop ``job``: its ``abort()`` after a failed step when it has one, else ``cancel()``."""
    stop = getattr(job, "abort", None) if failed else None
    (stop or job.cancel)()
