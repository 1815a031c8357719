"""How the agent carries out the operator's preemption of a run: the decisions, pure.

The operator preempts a running job by writing ``status.preemption`` (its
``PreemptionRequest``); the agent stops the run at its next episode boundary
(the connector's ``stop_at_episode_end``), or opens the grace window itself when
``episodeWaitSeconds`` run out, and the run ends ``preempted``. This module
holds what that decides: the reason the job is told, how long is left to wait,
and the run's result. It never touches the connector, the job or the API server
(``runner.JobRunner`` does).
"""

from __future__ import annotations

from datetime import datetime

from armnet_core import JobResult, JobStatus
from armnet_core.api import MAX_STOP_REASON
from armnet_core.resources import PreemptionRequest

#: ``armnet_agent_preemptions_total{stopped_at}``: the boundary came (or none was open), or the wait ran out.
STOPPED_AT_EPISODE_END = "episode_end"
STOPPED_AT_EPISODE_WAIT = "episode_wait"


def preempted_error(request: PreemptionRequest) -> str:
    """The preempted run's ``result.error``: the operator's message, whole."""
    return f"preempted: {request.message}"


def preemption_reason(request: PreemptionRequest) -> str:
    """What the job's interlock says (``is_shutting_down``'s reason): the error, cut to what ``agent.sock`` takes.

    Cut here, not on the way, so that the in-process connector and a pod's sidecar
    name the same words, and the agent recognises them in the connector's record.
    """
    return preempted_error(request)[:MAX_STOP_REASON]


def episode_wait_left(request: PreemptionRequest, now: datetime) -> float:
    """Seconds the run may still go on before the agent opens the grace window itself.

    Counted from ``requestedAt`` (an agent that restarts, or sees the request late,
    does not wait again from the start), never more than ``episodeWaitSeconds``
    (a clock of the operator's ahead of the agent's does not stretch it).
    """
    waited = (now - request.requested_at).total_seconds()
    return float(min(request.episode_wait_seconds, max(0.0, request.episode_wait_seconds - waited)))


def preempted_result(result: JobResult, request: PreemptionRequest | None, *, stopped: bool) -> JobResult:
    """The run's result once a preemption stopped it: ``preempted``, its error saying why.

    ``stopped``: the preemption opened the job's grace window before the job ended
    (the agent's graceful stop for it, or the connector's at the boundary), and no
    cancel came first. Then whatever the job did in that window is the preemption's
    doing, as in a cancel's window: a cancelled run, and a job that ended on its
    own (returned, or raised on the refused motion) before the agent's stop reached
    the supervisor, end ``preempted``, keeping their return value and output. A
    timeout keeps its own status (its grace window came first), and a run the
    preemption did not stop (it ended before the boundary) keeps its own result.
    """
    if request is None or not stopped:
        return result
    if result.status not in (JobStatus.CANCELLED, JobStatus.SUCCEEDED, JobStatus.FAILED):
        return result
    return result.model_copy(update={"status": JobStatus.PREEMPTED, "error": preempted_error(request)})
