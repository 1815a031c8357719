"""A finished job's stored outputs go with the job at its TTL, unless kept (``artifact_removal``).

The pure decision as a table; the lifecycle waiting for the node agent's upload; then
the pass on the in-memory API server and store: removed before the job, kept with the
annotation, and a store that does not answer keeps the job (the one pointer to its
outputs) until the next pass removes both.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import timedelta

import pytest
from armnet_core.api import KEEP_ARTIFACTS_ANNOTATION
from armnet_operator.artifact_removal import (
    UPLOAD_SETTLE_CAP,
    UPLOAD_START_WAIT,
    outputs_prefix,
    upload_pending,
)
from armnet_operator.lifecycle import DeleteJob, plan_lifecycle
from armnet_operator.reconcile import Memory, reconcile_once
from operator_builders import NOW, TIMING, a_job

from tests.unit.operator.operator_world import World

pytestmark = pytest.mark.unit

BUCKET = "outputs"
STORED = a_job().named("rec", "team-a").finished()
STORED = replace(STORED, uid="u-1", artifacts_location=f"s3://{BUCKET}/team-a/u-1/", artifacts_phase="Uploaded")


@pytest.mark.parametrize(("job", "bucket", "prefix"), [
    pytest.param(STORED, BUCKET, "team-a/u-1/", id="the job's own prefix"),
    pytest.param(STORED, None, None, id="no store"),
    pytest.param(replace(STORED, keep_artifacts=True), BUCKET, None, id="kept"),
    pytest.param(replace(STORED, artifacts_location=None), BUCKET, None, id="nothing stored"),
    pytest.param(STORED, "other", None, id="stored in another bucket"),
    pytest.param(replace(STORED, artifacts_location=f"s3://{BUCKET}/team-b/u-1/"), BUCKET, None,
                 id="another namespace's prefix"),
    pytest.param(replace(STORED, artifacts_location=f"s3://{BUCKET}/team-a/"), BUCKET, None, id="the whole namespace"),
    pytest.param(replace(STORED, uid="../u", artifacts_location=f"s3://{BUCKET}/team-a/../u/"), BUCKET, None,
                 id="a uid outside Kubernetes' syntax"),
])
def test_only_the_job_s_own_prefix_in_the_operator_s_bucket_is_removed(job, bucket, prefix) -> None:  # noqa: ANN001
    assert outputs_prefix(job, bucket) == prefix


WITH_STORE = replace(TIMING, outputs_store=True)
H = timedelta(hours=1)


@pytest.mark.parametrize(("phase", "ended_ago", "deleted"), [
    pytest.param("Uploaded", 6, True, id="stored"),
    pytest.param("Failed", 6, True, id="given up"),
    pytest.param("Discarded", 6, True, id="discarded"),
    pytest.param("Uploading", 6, False, id="uploading"),
    pytest.param("Retrying", 6, False, id="retrying"),
    pytest.param("Retrying", 5 + 24 * 3600 + 1, True, id="retrying a day past the TTL: an agent gone for good"),
    pytest.param(None, 6, False, id="no upload begun yet"),
    pytest.param(None, 11 * 60, True, id="none begun 10 minutes after the end"),
    pytest.param("Pending", 6, False, id="pending in the agent's queue"),
    pytest.param("Pending", 11 * 60, True, id="still pending 10 minutes after the end"),
])
def test_with_a_store_a_job_past_its_ttl_waits_for_its_upload_within_bounds(
        phase: str | None, ended_ago: float, deleted: bool) -> None:
    job = replace(a_job().with_ttl(5).without_finalizer().finished(seconds_ago=ended_ago), artifacts_phase=phase)
    assert any(isinstance(a, DeleteJob) for a in plan_lifecycle([job], [], NOW, WITH_STORE)) is deleted
    # Without a store nothing is removed with the job: nothing to wait for.
    assert any(isinstance(a, DeleteJob) for a in plan_lifecycle([job], [], NOW, TIMING))


def test_the_waits_are_bounded() -> None:
    ended = NOW - timedelta(seconds=6)
    job = replace(a_job().finished(seconds_ago=6), artifacts_phase="Uploading")
    assert upload_pending(job, NOW, ended) and not upload_pending(job, ended + UPLOAD_SETTLE_CAP, ended)
    fresh = replace(job, artifacts_phase=None)
    assert upload_pending(fresh, NOW, ended) and not upload_pending(fresh, ended + UPLOAD_START_WAIT, ended)
    assert UPLOAD_START_WAIT == timedelta(minutes=10) and UPLOAD_SETTLE_CAP == 24 * H


def finished_with_outputs(world: World, name: str, **annotations: str) -> str:
    """A job that ran, with a TTL of 1 s and outputs the agent stored; returns its prefix."""
    world.submit(name, "so-101", None, 0, ttlSecondsAfterFinished=1)
    body = world.jobs[f"t/{name}"]
    body["metadata"]["annotations"] = dict(annotations)
    prefix = f"t/{body['metadata']['uid']}/"
    body["status"] = {"phase": "succeeded", "finishedAt": body["metadata"]["creationTimestamp"],
                      "artifacts": {"phase": "Uploaded", "location": f"s3://{BUCKET}/{prefix}", "files": 2}}
    world.stored.update({f"{prefix}files/data.parquet": b"p", f"{prefix}manifest.json": b"{}"})
    return prefix


def one_pass(world: World, memory: Memory):  # noqa: ANN201 - the pass's Outcome
    jobs, cells = world.snapshot()
    return reconcile_once(jobs, cells, world.now, TIMING, world, memory)


def test_at_its_ttl_a_job_s_outputs_are_removed_before_it_and_a_kept_job_s_stay() -> None:
    world, memory = World(), Memory()
    world.outputs_bucket = BUCKET
    removed = finished_with_outputs(world, "gone")
    kept = finished_with_outputs(world, "kept", **{KEEP_ARTIFACTS_ANNOTATION: "true"})
    world.stored["t/other-uid/files/x"] = b"another job's"
    world.tick(2)
    outcome = one_pass(world, memory)
    assert sorted(world.jobs) == []
    assert not any(key.startswith(removed) for key in world.stored)
    assert sorted(world.stored) == sorted([f"{kept}files/data.parquet", f"{kept}manifest.json", "t/other-uid/files/x"])
    assert outcome.outputs_removed == {"removed": 1}


def test_a_keep_annotation_the_snapshot_does_not_show_yet_keeps_the_outputs() -> None:
    """The removal cannot be undone: it is decided again on the job as the server has it."""
    world, memory = World(), Memory()
    world.outputs_bucket = BUCKET
    prefix = finished_with_outputs(world, "rec")
    world.tick(2)
    jobs, cells = world.snapshot()  # the operator's view, from before the annotation
    world.jobs["t/rec"]["metadata"]["annotations"][KEEP_ARTIFACTS_ANNOTATION] = "true"
    reconcile_once(jobs, cells, world.now, TIMING, world, memory)
    assert "t/rec" not in world.jobs
    assert f"{prefix}manifest.json" in world.stored


def test_a_store_that_does_not_answer_keeps_the_job_until_its_outputs_are_removed() -> None:
    world, memory = World(), Memory()
    world.outputs_bucket, world.store_down = BUCKET, True
    prefix = finished_with_outputs(world, "rec")
    world.tick(2)
    outcome = one_pass(world, memory)
    assert "t/rec" in world.jobs and f"{prefix}manifest.json" in world.stored
    assert outcome.outputs_removed == {"failed": 1}
    world.store_down = False
    world.tick(1)
    one_pass(world, memory)
    assert "t/rec" not in world.jobs and not world.stored


def test_without_a_store_the_job_is_deleted_at_its_ttl_and_its_outputs_are_left() -> None:
    world, memory = World(), Memory()
    prefix = finished_with_outputs(world, "rec")
    world.tick(2)
    one_pass(world, memory)
    assert "t/rec" not in world.jobs and f"{prefix}manifest.json" in world.stored
