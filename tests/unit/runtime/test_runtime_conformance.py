"""Every public name of the SDK's documented API exists with its documented signature and
defaults (this module pins them: it is the reference), and importing ``armnet_runtime`` loads
nothing beyond the standard library and pydantic."""

from __future__ import annotations

import dataclasses
import inspect
import json
import subprocess
import sys
from typing import Any

import armnet_core
import armnet_runtime
import pytest
from armnet_runtime import cli, context, decorator, markers

pytestmark = pytest.mark.unit

E = inspect.Parameter.empty
KW = inspect.Parameter.KEYWORD_ONLY


def params(func: Any) -> list[tuple[str, Any, bool]]:
    """(name, default, keyword-only) of each parameter, ``self`` excluded."""
    signature = inspect.signature(func)
    return [
        (p.name, p.default, p.kind is KW)
        for p in signature.parameters.values()
        if p.name != "self"
    ]


PACKAGE_NAMES = [
    "Embodiment", "Task", "TerminalStatus", "BIMANUAL_SO101_EMBODIMENT", "SO101_EMBODIMENT",
    "Job", "JobResult", "JobSpec", "JobStatus", "RemoteExecutionError", "Cell",
    "CompletionStatus", "Context", "ResetTimeoutException", "MainRegistrationError",
    "require_so101_embodiment", "main",
]


@pytest.mark.parametrize("name", PACKAGE_NAMES)
def test_package_exports_the_reference_names(name: str) -> None:
    assert name in armnet_runtime.__all__
    assert hasattr(armnet_runtime, name)


def test_every_armnet_core_name_is_re_exported_unchanged() -> None:
    for name in armnet_core.__all__:
        assert getattr(armnet_runtime, name) is getattr(armnet_core, name), name
    assert set(armnet_core.__all__) <= set(armnet_runtime.__all__)
    assert len(set(armnet_runtime.__all__)) == len(armnet_runtime.__all__)
    assert all(hasattr(armnet_runtime, name) for name in armnet_runtime.__all__)


@pytest.mark.parametrize(
    ("func", "expected"),
    [
        (context.Cell.reset, []),
        (context.Cell.is_complete, [("block", False, True)]),
        (context.Cell.rollout_begin,
         [("index", None, True), ("total", None, True), ("outcome_controls", True, True)]),
        (context.Cell.rollout_end, []),
        (context.Cell.is_shutting_down, []),
        (context.Cell.should_stop, []),
        (context.Cell.get_teleop_action, []),
        (context.Cell.get_teleop_event, []),
        (context.Cell.prepare_bimanual_calibration_dir, []),
        (context.Cell.arm, [("name", E, False)]),
        (context.Context.report_progress, [("message", E, False)]),
        (context.Context.is_shutting_down, []),
        (context.Context.log_rerun_data,
         [("observation", None, False), ("action", None, False),
          ("compress_images", True, True), ("jpeg_quality", 75, True)]),
        (context.Volume.path, [("relative_path", E, False)]),
        (context.Volume.read_bytes, [("relative_path", E, False)]),
        (context.Volume.read_text, [("relative_path", E, False)]),
        (context.Volume.write_bytes, [("relative_path", E, False), ("data", E, False)]),
        (context.Volume.write_text, [("relative_path", E, False), ("data", E, False)]),
        (context.require_so101_embodiment, [("ctx", E, False), ("runtime_name", E, False)]),
        (context.build_context, []),
        (decorator.main, [("fn", E, False)]),
        (decorator.registered_main, []),
        (cli.run, [("argv", None, False)]),
        (markers.parse_marker_line, [("line", E, False)]),
        (armnet_core.JobResult.raise_for_status, []),
        (armnet_core.Job.is_terminal, []),
    ],
    ids=lambda value: getattr(value, "__qualname__", None) or "",
)
def test_signatures_match_the_reference(func: Any, expected: list[tuple[str, Any, bool]]) -> None:
    assert params(func) == expected


def dataclass_defaults(cls: type) -> list[tuple[str, Any]]:
    out = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            out.append((f.name, f.default))
        elif f.default_factory is not dataclasses.MISSING:
            out.append((f.name, f.default_factory()))
        else:
            out.append((f.name, E))
    return out


def test_cell_fields_and_defaults() -> None:
    assert dataclass_defaults(context.Cell) == [
        ("robot_port", None), ("robot_id", None), ("calibration_dir", None),
        ("calibration_file_path", None), ("language_instruction", None),
        ("local_control_endpoint", None), ("operator_call_endpoint", None),
        ("is_local_container", False), ("safety_limit", None), ("arms", {}),
    ]


def test_context_fields_and_defaults() -> None:
    fields = dataclass_defaults(context.Context)
    assert [name for name, _ in fields] == [
        "job_id", "embodiment", "task", "args", "cell", "camera_configs", "cache_home",
        "volume", "secrets", "timeout_seconds",
    ]
    defaults = dict(fields)
    assert defaults["args"] == {} and defaults["camera_configs"] == {} and defaults["secrets"] == {}
    assert defaults["cell"] == context.Cell() and defaults["volume"] == context.Volume()
    assert defaults["cache_home"] is None and defaults["timeout_seconds"] is None


def test_small_dataclasses_match_the_reference() -> None:
    assert dataclass_defaults(context.Volume) == [("root", None)]
    assert dataclass_defaults(context.RuntimeArm) == [
        ("name", E), ("robot_port", E), ("robot_id", None), ("calibration_dir", None),
        ("calibration_file_path", None), ("safety_limit", None),
    ]
    assert dataclass_defaults(context.BimanualCalibrationLayout) == [
        ("robot_id", E), ("calibration_dir", E),
    ]
    assert context.RuntimeArm.__dataclass_params__.frozen  # type: ignore[attr-defined]
    assert context.BimanualCalibrationLayout.__dataclass_params__.frozen  # type: ignore[attr-defined]
    assert context.CompletionStatus._fields == ("complete", "success")


def test_exception_bases() -> None:
    assert issubclass(context.ResetTimeoutException, RuntimeError)
    assert issubclass(decorator.MainRegistrationError, RuntimeError)
    assert issubclass(armnet_core.RemoteExecutionError, RuntimeError)


def test_model_fields_and_defaults() -> None:
    spec = armnet_core.JobSpec.model_fields
    assert list(spec) == [
        "image", "args", "embodiment", "task", "timeout_seconds", "secrets", "detach", "username",
    ]
    assert spec["image"].is_required() and spec["embodiment"].is_required()
    assert list(armnet_core.Job.model_fields) == [
        "id", "spec", "status", "created_at", "updated_at", "cell_id", "result", "dispatched",
    ]
    assert list(armnet_core.JobResult.model_fields) == [
        "status", "exit_code", "stdout", "stderr", "error", "traceback", "return_value",
        "started_at", "finished_at",
    ]
    assert armnet_core.JobResult.model_fields["stdout"].default == ""


def test_module_level_constants() -> None:
    assert context._TELEOP_READ_TIMEOUT_S == 0.5
    assert context.SO101_EMBODIMENT == "lerobot/so-101"
    assert context.BIMANUAL_SO101_EMBODIMENT == "lerobot/bimanual_so101"
    assert context.logger.name == "armnet_runtime.context"
    assert decorator.EntryPoint is not None


def test_console_script_entry_point_is_cli_main() -> None:
    from importlib.metadata import entry_points

    [script] = [ep for ep in entry_points(group="console_scripts") if ep.name == "armnet-runtime"]
    assert script.value == "armnet_runtime.cli:main"


_PURITY_PROBE = """
import json, sys
before = set(sys.modules)
import armnet_runtime, armnet_runtime.cli, armnet_runtime.markers, armnet_runtime.rerun
loaded = sorted({name.split('.')[0] for name in set(sys.modules) - before})
print(json.dumps(loaded))
"""
ALLOWED_THIRD_PARTY = {
    "armnet_core", "armnet_runtime", "pydantic", "pydantic_core", "typing_extensions",
    "annotated_types", "typing_inspection",
}


def test_importing_the_sdk_loads_only_stdlib_and_pydantic() -> None:
    out = subprocess.run(
        [sys.executable, "-c", _PURITY_PROBE], capture_output=True, text=True, check=True
    )
    loaded = set(json.loads(out.stdout))
    foreign = {
        name for name in loaded
        if name not in sys.stdlib_module_names and name not in ALLOWED_THIRD_PARTY
        and not name.startswith("_")
    }
    assert foreign == set(), f"import armnet_runtime pulled in {sorted(foreign)}"
    assert {"numpy", "cv2", "lerobot", "torch", "google"}.isdisjoint(loaded)
