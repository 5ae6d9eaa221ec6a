"""One way to run an engine job from an operator: blocking, or modal in timer-sized chunks.

Every long operator (Analyze, Track, Auto Focus, Render) is a :class:`JobOperator`: it says
how to build its job (``_prepare``: read Blender state into a plain plan, create the engine
job, which checks its inputs) and what to do with a finished one (``_apply``: write strips,
properties, F-curves in one step). Every job is a :class:`rvr_addon.jobs.Job`: ``step() ->
bool``, ``progress`` (0..1), ``text`` and ``cancel()`` (and ``abort()`` for a failure, when it
has one); ``_prepare`` returning anything else is refused at once.

* ``execute()`` loops ``while job.step()`` (scripts, ``blender -b``), with ``wm.progress_*``.
* ``invoke()`` with a window adds a timer and a modal handler; ``modal()`` steps the job for
  at most ``STEP_BUDGET_S`` per ``TIMER`` event (the UI stays responsive), shows the progress
  in the panel (WindowManager properties) and the status bar, stops on Esc or when
  ``rvr.cancel_job`` asks, and always leaves through ``_finish()``, which removes the timer and
  resets ``wm.rvr_job_status`` to IDLE whatever happens (a cancel or an abort that raises, too):
  a stuck RUNNING/CANCELLING status would grey out every RVR operator until the file is reloaded.

Nothing touches bpy off the main thread: the job runs in the timer's chunks.
"""
from __future__ import annotations

import time

import bpy

from ..rvr_addon.errors import RvrError
from ..rvr_addon.jobs import check_job, stop_job

TIMER_PERIOD_S = 0.1
STEP_BUDGET_S = 0.9 * TIMER_PERIOD_S


def step_for(job, budget_s: float) -> bool:
    """Step ``job`` for about ``budget_s`` seconds (at least one step); False once it is done."""
    deadline = time.perf_counter() + budget_s
    while job.step():
        if time.perf_counter() >= deadline:
            return True
    return False


def set_status(context, status: str, text: str = "", progress: float = 0.0) -> None:
    wm = context.window_manager
    wm.rvr_job_status = status
    wm.rvr_job_text = text
    wm.rvr_job_progress = progress


def job_running(context) -> bool:
    return context.window_manager.rvr_job_status != "IDLE"


def _status_bar(context, text: str | None) -> None:
    workspace = getattr(context, "workspace", None)
    if workspace is not None and not bpy.app.background:
        workspace.status_text_set(text)


def _abort(job) -> None:
    stop_job(job, failed=True)


class JobOperator:
    """Mixin for an operator running one engine job (see the module docstring).

    Subclasses define ``job_label`` (for messages), ``_prepare(context) -> (plan, job)`` and
    ``_apply(context, plan, job)``; both raise RvrError for bad input.
    """

    job_label = "Refocus job"
    _timer = None
    _job = None
    _plan = None

    def _prepare(self, context):  # pragma: no cover - abstract
        raise NotImplementedError

    def _apply(self, context, plan, job) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _prepare_job(self, context):
        """``_prepare`` with its job checked against the Job protocol."""
        plan, job = self._prepare(context)
        return plan, check_job(job)

    def execute(self, context) -> set[str]:
        try:
            plan, job = self._prepare_job(context)
        except RvrError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            while job.step():
                wm.progress_update(int(100 * job.progress))
            self._apply(context, plan, job)
        except RvrError as ex:
            _abort(job)
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        except KeyboardInterrupt:
            job.cancel()
            self.report({"WARNING"}, f"{self.job_label} {job.text}; nothing was changed")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        return {"FINISHED"}

    def invoke(self, context, event) -> set[str]:
        if bpy.app.background or context.window is None:  # no event loop: run blocking
            return self.execute(context)
        if job_running(context):
            self.report({"WARNING"}, "A refocus job is already running; wait for it or cancel it (Esc)")
            return {"CANCELLED"}
        try:
            self._plan, self._job = self._prepare_job(context)
        except RvrError as ex:
            self.report({"ERROR"}, str(ex))
            return {"CANCELLED"}
        wm = context.window_manager
        set_status(context, "RUNNING", f"{self.job_label}: {self._job.text}", 0.0)
        try:
            _status_bar(context, f"{self.job_label}: {self._job.text}  (Esc to cancel)")
            self._timer = wm.event_timer_add(TIMER_PERIOD_S, window=context.window)
            wm.modal_handler_add(self)
        except BaseException:  # no modal run after all: stop the job, leave the status IDLE
            try:
                self._job.cancel()
            finally:
                self._finish(context, {"CANCELLED"})
            raise
        return {"RUNNING_MODAL"}

    def modal(self, context, event) -> set[str]:
        if self._job is None:  # ended already (Blender's cancel()): nothing to run, another job's status stays
            return {"CANCELLED"}
        if event.type == "ESC" or context.window_manager.rvr_job_status == "CANCELLING":
            try:
                self._job.cancel()
                self.report({"WARNING"}, f"{self.job_label} {self._job.text}; nothing else was changed")
            except RvrError as ex:
                self.report({"ERROR"}, f"{self.job_label} cancelled: {ex}")
            finally:
                self._finish(context, {"CANCELLED"})
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            running = step_for(self._job, STEP_BUDGET_S)
            if not running:
                self._apply(context, self._plan, self._job)
                return self._finish(context, {"FINISHED"})
        except RvrError as ex:
            try:
                _abort(self._job)
            finally:
                self.report({"ERROR"}, str(ex))
                self._finish(context, {"CANCELLED"})
            return {"CANCELLED"}
        except BaseException:
            try:
                _abort(self._job)
            finally:
                self._finish(context, {"CANCELLED"})
            raise
        wm = context.window_manager
        wm.rvr_job_progress = 100.0 * self._job.progress
        wm.rvr_job_text = f"{self.job_label}: {self._job.text} ({100 * self._job.progress:.0f}%)"
        _status_bar(context, f"{wm.rvr_job_text}  (Esc to cancel)")
        return {"PASS_THROUGH"}

    def _finish(self, context, result: set[str]) -> set[str]:
        """The one exit of the modal run: remove the timer, reset the status and the status bar."""
        try:
            if self._timer is not None:
                timer, self._timer = self._timer, None
                context.window_manager.event_timer_remove(timer)
        finally:
            text = f"{self.job_label}: {getattr(self._job, 'text', '')}" if self._job is not None else ""
            set_status(context, "IDLE", text, 0.0)
            self._job = None
            self._plan = None
            _status_bar(context, None)
        return result

    def cancel(self, context) -> None:
        """Blender ends the modal run (file load, window closed): stop the job, clean up."""
        try:
            if self._job is not None:
                self._job.cancel()
        finally:
            self._finish(context, {"CANCELLED"})
