"""Context pieces that need no peer: Volume rules, @main registry, embodiment checks, calibration."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from armnet_runtime import decorator
from armnet_runtime.context import (
    BimanualCalibrationLayout,
    Cell,
    CompletionStatus,
    Context,
    RuntimeArm,
    Volume,
    require_so101_embodiment,
)
from armnet_runtime.decorator import MainRegistrationError, main, registered_main

pytestmark = pytest.mark.unit


@pytest.fixture
def clean_registry() -> Iterator[None]:
    decorator._clear_registration()
    yield
    decorator._clear_registration()


# --- Volume ---------------------------------------------------------------------------------


def test_volume_paths_are_relative_to_the_root(tmp_path: Path) -> None:
    volume = Volume(root=tmp_path)
    assert volume.path("a/b.txt") == tmp_path / "a" / "b.txt"
    assert volume.path(Path("c")) == tmp_path / "c"


@pytest.mark.parametrize("bad", ["/etc/passwd", "../escape", "a/../../b", Path("x/../y")])
def test_volume_refuses_absolute_and_parent_paths(tmp_path: Path, bad: str | Path) -> None:
    with pytest.raises(ValueError, match="relative and must not contain '..'"):
        Volume(root=tmp_path).path(bad)


def test_an_unmounted_volume_says_so() -> None:
    with pytest.raises(RuntimeError, match="volume is not mounted"):
        Volume().read_text("x")


def test_volume_writes_create_parents_and_read_back(tmp_path: Path) -> None:
    volume = Volume(root=tmp_path)
    assert volume.write_text("runs/1/metrics.json", '{"a": 1}') == tmp_path / "runs/1/metrics.json"
    assert volume.read_text("runs/1/metrics.json") == '{"a": 1}'
    assert volume.write_bytes("blob/x.bin", b"\x00\x01") == tmp_path / "blob/x.bin"
    assert volume.read_bytes("blob/x.bin") == b"\x00\x01"


# --- @main ----------------------------------------------------------------------------------


def test_main_registers_and_returns_the_function(clean_registry: None) -> None:
    def run(ctx: Context) -> int:
        return 1

    assert registered_main() is None
    assert main(run) is run
    assert registered_main() is run


def test_a_second_main_raises_with_the_documented_message(clean_registry: None) -> None:
    def first(ctx: Context) -> None: ...

    def second(ctx: Context) -> None: ...

    main(first)
    with pytest.raises(MainRegistrationError) as info:
        main(second)
    here = __name__
    assert str(info.value) == (
        "armnet: multiple @main-decorated functions found "
        f"(already registered: {here}.test_a_second_main_raises_with_the_documented_message.<locals>.first; "
        f"new: {here}.test_a_second_main_raises_with_the_documented_message.<locals>.second). "
        "Only one entry point per container is supported."
    )
    assert registered_main() is first
    assert isinstance(info.value, RuntimeError)


# --- embodiment and arms --------------------------------------------------------------------

LEFT_RIGHT = {
    "left": RuntimeArm(name="left", robot_port="unix:///r.sock?arm=left", robot_id="l"),
    "right": RuntimeArm(name="right", robot_port="unix:///r.sock?arm=right", robot_id="r"),
}


def ctx_for(embodiment: str, arms: dict[str, RuntimeArm] | None = None) -> Context:
    return Context(job_id="j", embodiment=embodiment, task="t", cell=Cell(arms=arms or {}))


def test_single_so101_is_not_bimanual() -> None:
    assert require_so101_embodiment(ctx_for("lerobot/so-101"), "my-runtime") is False


def test_bimanual_so101_needs_left_and_right() -> None:
    assert require_so101_embodiment(ctx_for("lerobot/bimanual_so101", LEFT_RIGHT), "rt") is True
    with pytest.raises(RuntimeError, match=r"expects two arms \(left\+right\), .*arms=\[\]"):
        require_so101_embodiment(ctx_for("lerobot/bimanual_so101"), "rt")
    with pytest.raises(RuntimeError, match="expects a single arm"):
        require_so101_embodiment(ctx_for("lerobot/so-101", LEFT_RIGHT), "rt")


def test_other_embodiments_are_not_implemented() -> None:
    with pytest.raises(NotImplementedError, match="my-runtime supports 'lerobot/so-101'.*got 'arx/x5'"):
        require_so101_embodiment(ctx_for("arx/x5"), "my-runtime")


def test_cell_arm_lookup_names_the_missing_arm() -> None:
    cell = Cell(arms=LEFT_RIGHT)
    assert cell.arm("left").robot_id == "l"
    with pytest.raises(KeyError, match="cell has no arm named 'middle'"):
        cell.arm("middle")
    assert cell.is_bimanual and not Cell(arms={"left": LEFT_RIGHT["left"]}).is_bimanual


def test_completion_status_is_truthy_iff_complete_and_unpacks() -> None:
    complete, success = CompletionStatus(complete=True, success=False)
    assert (complete, success) == (True, False)
    assert bool(CompletionStatus(True, False)) and not CompletionStatus(False, True)


def test_runtime_arm_is_frozen() -> None:
    with pytest.raises(AttributeError):
        LEFT_RIGHT["left"].robot_id = "other"  # type: ignore[misc]


# --- bimanual calibration ------------------------------------------------------------------


def write_calibration(path: Path, marker: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"shoulder_pan": {"id": 1, "marker": marker}}))
    return path


def test_bimanual_calibration_is_laid_out_with_lerobots_names(tmp_path: Path) -> None:
    write_calibration(tmp_path / "cell" / "l-id.json", "from cell dir")
    right_file = write_calibration(tmp_path / "elsewhere" / "right.json", "from file path")
    cell = Cell(
        robot_id="pair",
        calibration_dir=tmp_path / "cell",
        arms={
            "left": RuntimeArm(name="left", robot_port="p", robot_id="l-id"),
            "right": RuntimeArm(name="right", robot_port="p", robot_id="r-id",
                                calibration_file_path=right_file),
        },
    )
    layout = cell.prepare_bimanual_calibration_dir()
    assert isinstance(layout, BimanualCalibrationLayout) and layout.robot_id == "pair"
    assert sorted(p.name for p in layout.calibration_dir.iterdir()) == [
        "pair_left.json", "pair_right.json",
    ]
    assert "from cell dir" in (layout.calibration_dir / "pair_left.json").read_text()
    assert "from file path" in (layout.calibration_dir / "pair_right.json").read_text()
    shutil.rmtree(layout.calibration_dir)


def test_an_arms_own_calibration_dir_wins_over_the_cells(tmp_path: Path) -> None:
    write_calibration(tmp_path / "cell" / "l-id.json", "cell")
    write_calibration(tmp_path / "arm" / "l-id.json", "arm")
    write_calibration(tmp_path / "cell" / "r-id.json", "cell")
    cell = Cell(
        robot_id="pair", calibration_dir=tmp_path / "cell",
        arms={"left": RuntimeArm("left", "p", "l-id", calibration_dir=tmp_path / "arm"),
              "right": RuntimeArm("right", "p", "r-id")},
    )
    layout = cell.prepare_bimanual_calibration_dir()
    assert '"arm"' in (layout.calibration_dir / "pair_left.json").read_text()
    shutil.rmtree(layout.calibration_dir)


def test_missing_bimanual_calibration_says_where_it_looked(tmp_path: Path) -> None:
    cell = Cell(robot_id="pair", calibration_dir=tmp_path, arms=LEFT_RIGHT)
    with pytest.raises(RuntimeError, match=f"no calibration file found for left arm.*{tmp_path}/l.json"):
        cell.prepare_bimanual_calibration_dir()


def test_bimanual_calibration_needs_two_arms_and_a_robot_id() -> None:
    with pytest.raises(RuntimeError, match="requires left and right arms"):
        Cell(robot_id="x").prepare_bimanual_calibration_dir()
    with pytest.raises(RuntimeError, match="requires ctx.cell.robot_id"):
        Cell(arms=LEFT_RIGHT).prepare_bimanual_calibration_dir()


def test_report_progress_prints_the_marker(capsys: pytest.CaptureFixture[str]) -> None:
    ctx_for("lerobot/so-101").report_progress("halfway")
    assert capsys.readouterr().out == "[armnet:progress] halfway\n"


def test_context_is_shutting_down_delegates_to_the_cell() -> None:
    assert ctx_for("lerobot/so-101").is_shutting_down() is False
