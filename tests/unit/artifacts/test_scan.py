"""The walk of a job's output directory: hostile trees are bounded, refused or stored safely."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from armnet_node.artifacts.model import OutputLimits, OutputTooLarge
from armnet_node.artifacts.scan import LINK_OUT, LINK_TO_DIRECTORY, NOT_A_FILE, scan_output

pytestmark = pytest.mark.unit


def _tree(root: Path, files: dict[str, bytes]) -> Path:
    for name, data in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    return root


def test_every_regular_file_is_listed_with_its_size_in_path_order(tmp_path: Path) -> None:
    _tree(tmp_path, {"b.txt": b"bb", "data/chunk-000/episode_0.parquet": b"p" * 10, "a.txt": b"a"})
    scan = scan_output(tmp_path, OutputLimits())
    assert [(f.path, f.size) for f in scan.files] == [
        ("a.txt", 1), ("b.txt", 2), ("data/chunk-000/episode_0.parquet", 10)]
    assert scan.refused == ()
    assert scan.total_bytes == 13


def test_a_missing_directory_is_an_empty_output(tmp_path: Path) -> None:
    scan = scan_output(tmp_path / "never-created", OutputLimits())
    assert scan.files == () and scan.refused == ()


def test_a_symlink_out_of_the_directory_is_refused(tmp_path: Path) -> None:
    secret = tmp_path / "host-secret"
    secret.write_bytes(b"agent credentials")
    out = tmp_path / "out"
    out.mkdir()
    (out / "steal").symlink_to(secret)
    (out / "etc").symlink_to("/etc")
    (out / "up").symlink_to("..")
    scan = scan_output(out, OutputLimits())
    assert scan.files == ()
    assert {(r.path, r.reason) for r in scan.refused} == {("steal", LINK_OUT), ("etc", LINK_OUT), ("up", LINK_OUT)}


def test_a_symlink_to_a_file_inside_is_stored_under_its_own_name(tmp_path: Path) -> None:
    _tree(tmp_path, {"videos/front.mp4": b"video"})
    (tmp_path / "latest.mp4").symlink_to("videos/front.mp4")
    scan = scan_output(tmp_path, OutputLimits())
    latest = next(f for f in scan.files if f.path == "latest.mp4")
    assert latest.source == (tmp_path / "videos/front.mp4").resolve()
    assert latest.size == 5


def test_a_symlink_loop_to_a_directory_inside_is_not_followed(tmp_path: Path) -> None:
    _tree(tmp_path, {"d/x": b"x"})
    (tmp_path / "d" / "again").symlink_to("..")
    scan = scan_output(tmp_path, OutputLimits())
    assert [f.path for f in scan.files] == ["d/x"]
    assert [(r.path, r.reason) for r in scan.refused] == [("d/again", LINK_TO_DIRECTORY)]


def test_a_fifo_is_refused_without_being_opened(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "pipe")  # opening it for reading would block the agent forever
    scan = scan_output(tmp_path, OutputLimits())
    assert [(r.path, r.reason) for r in scan.refused] == [("pipe", NOT_A_FILE)]


def test_a_name_that_is_not_utf8_is_refused_with_the_reason(tmp_path: Path) -> None:
    (tmp_path / os.fsdecode(b"bad\xff")).write_bytes(b"x")
    (tmp_path / "ok").write_bytes(b"y")
    scan = scan_output(tmp_path, OutputLimits())
    assert [f.path for f in scan.files] == ["ok"]
    assert [(r.path, r.reason) for r in scan.refused] == [("bad\\xff", "the name is not valid UTF-8")]


def test_ten_thousand_tiny_files_stop_at_the_cap_with_a_clear_error(tmp_path: Path) -> None:
    for i in range(10_000):
        (tmp_path / f"f{i:05d}").write_bytes(b"")
    with pytest.raises(OutputTooLarge, match="more than 1000 entries"):
        scan_output(tmp_path, OutputLimits(max_files=1000))


def test_directories_count_against_the_entry_cap(tmp_path: Path) -> None:
    for i in range(50):
        (tmp_path / f"d{i}").mkdir()
    with pytest.raises(OutputTooLarge):
        scan_output(tmp_path, OutputLimits(max_files=49))
    assert scan_output(tmp_path, OutputLimits(max_files=50)).files == ()


def test_bytes_over_the_cap_are_refused_before_any_upload(tmp_path: Path) -> None:
    _tree(tmp_path, {"a": b"x" * 600, "b": b"x" * 600})
    with pytest.raises(OutputTooLarge, match="more than 1000 bytes"):
        scan_output(tmp_path, OutputLimits(max_bytes=1000))
    assert scan_output(tmp_path, OutputLimits(max_bytes=1200)).total_bytes == 1200


def test_the_cell_s_record_is_stored_under_armnet_cell_and_a_job_cannot_pass_its_files_off_as_the_cell_s(
    tmp_path: Path,
) -> None:
    from armnet_node.artifacts.scan import RESERVED, scan_job_output

    out = _tree(tmp_path / "out", {"data.parquet": b"d", "armnet-cell/rollouts.json": b"forged",
                                   "deep/armnet-cell/x": b"fine below the top", ".job.partial": b"the job's own"})
    # A part the connector was still writing when the scan came (a connector killed mid-write): not stored.
    record = _tree(tmp_path / "record", {"rollouts.json": b"{}", "rollouts/000001-t/first.jpg": b"j",
                                         "servo-trace/.part-000002.parquet.partial": b"half"})
    scan = scan_job_output(out, record, OutputLimits())
    assert [f.path for f in scan.files] == [
        ".job.partial", "armnet-cell/rollouts.json", "armnet-cell/rollouts/000001-t/first.jpg", "data.parquet",
        "deep/armnet-cell/x"]
    assert {f.path: f.source for f in scan.files}["armnet-cell/rollouts.json"] == (record / "rollouts.json").resolve()
    assert [(r.path, r.reason) for r in scan.refused] == [("armnet-cell", RESERVED)]
    # Without a record (no monitor, or a local run) the job's output alone, its armnet-cell still refused.
    assert [r.path for r in scan_job_output(out, None, OutputLimits()).refused] == ["armnet-cell"]
