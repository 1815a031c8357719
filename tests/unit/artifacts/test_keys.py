"""Object keys and the manifest: what a job's output may become in the bucket."""

from __future__ import annotations

import json
import os

import pytest
from armnet_core.output_keys import job_prefix
from armnet_node.artifacts.keys import (
    MAX_KEY_BYTES,
    already_stored,
    build_manifest,
    manifest_key,
    name_refusal,
    object_key,
    printable,
)
from armnet_node.artifacts.model import Artifact, Refused

pytestmark = pytest.mark.unit

PREFIX = "team-a/0f8e5b7a-1c2d-4e5f-8a9b-0c1d2e3f4a5b/"


def test_a_job_prefix_is_its_namespace_then_its_uid() -> None:
    assert job_prefix("team-a", "0f8e5b7a-1c2d") == "team-a/0f8e5b7a-1c2d/"


@pytest.mark.parametrize(("namespace", "uid"), [
    ("../other", "u1"), ("team-a/x", "u1"), ("Team", "u1"), ("", "u1"), ("team-a", "../u"), ("team-a", "a/b"),
])
def test_a_prefix_cannot_reach_another_namespace(namespace: str, uid: str) -> None:
    with pytest.raises(ValueError):
        job_prefix(namespace, uid)


def test_files_live_apart_from_the_manifest() -> None:
    assert object_key(PREFIX, "manifest.json") != manifest_key(PREFIX)
    assert object_key(PREFIX, "data/episode_0.parquet") == PREFIX + "files/data/episode_0.parquet"


@pytest.mark.parametrize("path", ["..", "../x", "a/../../b", "a/./b", "a//b", "./a", "a/"])
def test_dot_dot_and_empty_segments_are_refused(path: str) -> None:
    assert name_refusal(PREFIX, path) is not None


@pytest.mark.parametrize("path", ["a..b", "..hidden", "dir/x..", "données/épisode 1.mp4", "a\\b"])
def test_names_that_only_look_like_dots_are_stored(path: str) -> None:
    assert name_refusal(PREFIX, path) is None


def test_undecodable_and_control_names_are_refused_and_printed_escaped() -> None:
    undecodable = os.fsdecode(b"bad\xff.bin")
    assert name_refusal(PREFIX, undecodable) == "the name is not valid UTF-8"
    assert name_refusal(PREFIX, "line\nbreak") == "the name holds a control character"
    assert printable(undecodable) == "bad\\xff.bin"
    assert printable("line\nbreak") == "line\\x0abreak"


def test_a_key_over_s3s_limit_is_refused() -> None:
    assert name_refusal(PREFIX, "a" * (MAX_KEY_BYTES - len(PREFIX) - len("files/"))) is None
    assert "too long" in (name_refusal(PREFIX, "a" * (MAX_KEY_BYTES - len(PREFIX) - len("files/") + 1)) or "")


def test_a_stored_object_is_the_file_only_with_the_same_size_and_checksum() -> None:
    assert already_stored(3, "abc", 3, "abc")
    assert not already_stored(3, "abc", 3, "abd")
    assert not already_stored(3, "abc", 4, "abc")
    assert not already_stored(3, "abc", 3, None)  # an object written by something else
    assert not already_stored(3, "abc", None, None)


def test_the_manifest_lists_files_and_says_what_was_left_out() -> None:
    artifact = Artifact("a.txt", PREFIX + "files/a.txt", 5, "e" * 64)
    body = json.loads(build_manifest("team-a", "uid-1", [artifact], [Refused("link", "a link out")],
                                     [Refused("grow.log", "changed")]))
    assert body["files"] == [{"path": "a.txt", "key": PREFIX + "files/a.txt", "bytes": 5, "sha256": "e" * 64}]
    assert body["bytes"] == 5
    assert body["refused"] == [{"path": "link", "reason": "a link out"}]
    assert body["complete"] is False  # a changed file was not stored whole
    assert body["changedCount"] == 1


def test_the_manifests_list_of_refusals_is_bounded_but_counted() -> None:
    body = json.loads(build_manifest("team-a", "uid-1", [], [Refused(f"l{i}", "x") for i in range(5000)], []))
    assert len(body["refused"]) < 5000
    assert body["refusedCount"] == 5000
    assert body["complete"] is True
