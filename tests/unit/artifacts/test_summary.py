"""``status.artifacts`` from an upload's outcome: a summary a user acts on, bounded whatever the job wrote."""

from __future__ import annotations

import pytest
from armnet_node.artifacts import Artifact, Refused, UploadReport, summary

pytestmark = pytest.mark.unit


def a_report(*, refused: tuple[Refused, ...] = (), changed: tuple[Refused, ...] = ()) -> UploadReport:
    return UploadReport(
        bucket="outputs", prefix="team-a/uid-1/", manifest_key="team-a/uid-1/manifest.json",
        artifacts=(Artifact("a.parquet", "team-a/uid-1/files/a.parquet", 100, "0" * 64),
                   Artifact("b.mp4", "team-a/uid-1/files/b.mp4", 900, "1" * 64)),
        refused=refused, changed=changed, uploaded_bytes=1000, already_stored=0,
    )


def test_a_whole_upload_says_where_and_how_much_and_nothing_else() -> None:
    assert summary.uploaded(a_report()) == {
        "phase": "Uploaded", "location": "s3://outputs/team-a/uid-1/",
        "manifest": "s3://outputs/team-a/uid-1/manifest.json", "files": 2, "bytes": 1000, "complete": True,
        "leftOut": 0,
    }


def test_entries_left_out_are_named_changed_files_first_and_the_rest_counted() -> None:
    refused = tuple(Refused(f"link-{i}", "a symbolic link that leads out of the output directory (not followed)")
                    for i in range(5))
    changed = (Refused("log.txt", "changed while it was uploaded"),)

    status = summary.uploaded(a_report(refused=refused, changed=changed))

    assert (status["complete"], status["leftOut"]) == (False, 6)
    assert status["message"].startswith("6 entries were not stored: log.txt: changed while it was uploaded; link-0:")
    assert status["message"].endswith("(and 3 more: see the manifest)")


def test_the_message_stays_within_the_crd_s_bound_whatever_the_names() -> None:
    refused = tuple(Refused("d/" * 500 + f"{i}", "a name with a control character") for i in range(3))

    message = summary.uploaded(a_report(refused=refused))["message"]

    assert len(message) == summary.MESSAGE_MAX and message.endswith("…")


def test_a_retry_keeps_the_store_s_error_and_says_the_output_is_kept() -> None:
    status = summary.retrying("outputs", "team-a/uid-1/", "the object store did not answer")

    assert status["phase"] == "Retrying" and status["location"] == "s3://outputs/team-a/uid-1/"
    assert status["message"] == ("the object store did not answer; the output is kept on the robot host and the "
                                 "upload is retried")


def test_pending_is_the_phase_written_with_the_terminal_status_and_a_client_waits_it_out() -> None:
    from armnet_core.api import ARTIFACTS_IN_PROGRESS

    assert summary.pending() == {"phase": "Pending"}
    assert {summary.PENDING, summary.UPLOADING, summary.RETRYING} == ARTIFACTS_IN_PROGRESS
    assert not {summary.UPLOADED, summary.FAILED, summary.DISCARDED} & ARTIFACTS_IN_PROGRESS
