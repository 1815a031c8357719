"""Subjects are per tenant namespace and job; message ids are deterministic per line."""

from __future__ import annotations

import pytest
from armnet_node.streams import fms_subject, line_msg_id, log_subject, teleop_subject

pytestmark = pytest.mark.unit


def test_log_subjects_name_the_namespace_the_job_and_the_kind() -> None:
    assert log_subject("tenant-a", "0c1d-uid", "stdout") == "logs.tenant-a.0c1d-uid.stdout"


def test_operator_input_subjects_name_the_job_or_the_cell() -> None:
    assert teleop_subject("tenant-a", "uid", "action") == "teleop.tenant-a.uid.action"
    assert fms_subject("cell-1", "reset.confirm") == "fms.cell-1.reset.confirm"


def test_a_line_msg_id_is_the_job_the_stream_and_the_line_number() -> None:
    assert line_msg_id("uid", "stderr", 42) == "uid:stderr:42"


@pytest.mark.parametrize("bad", ["", "a b", "a*", "a>", "a\nb"])
def test_a_token_that_would_change_the_subject_is_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="cannot be part of a NATS subject"):
        log_subject(bad, "uid", "stdout")
    with pytest.raises(ValueError, match="cannot be part of a NATS subject"):
        fms_subject(bad, "stop")
