"""``armnet-runtime SCRIPT`` run as a real subprocess: exit codes, markers, timestamped streams."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest
from armnet_runtime import cli
from armnet_runtime.markers import Marker, parse_marker_line, split_timestamp
from armnet_runtime.rerun import ENCODING_JPEG, decode_packet

pytestmark = [pytest.mark.unit, pytest.mark.timeout(120)]

REPO = Path(__file__).resolve().parents[3]
HELLO = REPO / "runtime" / "examples" / "hello.py"
JOB_ENV = {"ARMNET_JOB_ID": "job-42", "ARMNET_EMBODIMENT": "lerobot/so-101", "ARMNET_TASK": "demo"}
# Most runs are local-container runs (the LeRobot import swap is then skipped by design);
# the hello run and the start-up test keep the swap.
FAST_ENV = {**JOB_ENV, "ARMNET_LOCAL_CONTAINER": "1"}


def console_script() -> str:
    path = Path(sys.executable).parent / "armnet-runtime"
    if not path.exists():
        pytest.fail(f"{path} is missing: install the SDK with `pip install -e runtime` in this venv")
    return str(path)


@dataclass
class Run:
    code: int
    stdout: str
    stderr: str

    def markers(self) -> list[Marker]:
        parsed = [parse_marker_line(line) for line in self.stdout.splitlines()]
        return [m for m in parsed if m is not None]

    def of_kind(self, kind: str) -> list[object]:
        return [m.payload for m in self.markers() if m.kind == kind]


def run_script(
    script: Path, *, env: dict[str, str] | None = None, stdin: str = "", argv: list[str] | None = None
) -> Run:
    base = {k: v for k, v in os.environ.items() if not k.startswith(("ARMNET_", "REMOTEROBOT_"))}
    base.update(FAST_ENV if env is None else env)
    proc = subprocess.run(
        [console_script(), *([str(script)] if argv is None else argv)],
        env=base, input=stdin, capture_output=True, text=True, timeout=100, cwd="/",
    )
    return Run(proc.returncode, proc.stdout, proc.stderr)


def write(tmp_path: Path, source: str, name: str = "main.py") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(source))
    return path


def test_exit_codes_have_the_documented_values() -> None:
    assert (cli.EXIT_OK, cli.EXIT_USER_RAISED, cli.EXIT_USAGE, cli.EXIT_NO_MAIN,
            cli.EXIT_USER_IMPORT_FAILED, cli.EXIT_BAD_CONTEXT) == (0, 1, 2, 3, 4, 5)


def test_hello_succeeds_with_progress_and_a_result_marker() -> None:
    """The full path; LeRobot is installed in the test venv, but a job that does not import it
    never loads it (the import swap waits for the job's own import)."""
    result = run_script(HELLO, env={**JOB_ENV, "ARMNET_ARGS": '{"name": "armnet", "steps": 2}'})
    assert result.code == 0, result.stderr
    assert result.of_kind("progress") == ["hello, armnet", "step 1/2", "step 2/2"]
    assert result.of_kind("result") == [{"greeting": "hello, armnet", "steps": 2, "job_id": "job-42"}]
    assert result.of_kind("traceback") == []
    assert "LeRobot" not in result.stderr


def test_a_job_that_does_not_import_lerobot_reaches_main_without_lerobot_or_torch(tmp_path: Path) -> None:
    """The platform's work before ``@main`` imports neither (the swap waits for the job's import),
    even on a cell with cameras, whose configs would be LeRobot's objects."""
    script = write(tmp_path, """
        import sys
        from armnet_runtime import main

        @main
        def run(ctx):
            heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("lerobot", "torch"))
            return {"heavy": heavy, "front": type(ctx.camera_configs["front"]).__name__}
    """)
    cameras = '{"camera_configs": {"front": {"index_or_path": 0, "fps": 30}}}'
    result = run_script(script, env={**JOB_ENV, "ARMNET_CELL_CONFIG": cameras})
    assert result.code == 0, result.stderr
    assert result.of_kind("result") == [{"heavy": [], "front": "dict"}]


def test_every_output_line_carries_a_utc_timestamp(tmp_path: Path) -> None:
    script = write(tmp_path, """
        import sys
        from armnet_runtime import main

        @main
        def run(ctx):
            print("plain line")
            print("to stderr", file=sys.stderr)
            return 1
    """)
    result = run_script(script)
    assert result.code == 0
    lines = result.stdout.splitlines() + result.stderr.splitlines()
    assert lines and all(split_timestamp(line)[0] is not None for line in lines)
    assert any(line.endswith("Z plain line") for line in result.stdout.splitlines())
    assert any(line.endswith("Z to stderr") for line in result.stderr.splitlines())
    assert all(m.timestamp is not None for m in result.markers())


def test_a_raise_exits_1_with_a_traceback_marker(tmp_path: Path) -> None:
    script = write(tmp_path, """
        from armnet_runtime import main

        @main
        def run(ctx):
            raise ValueError("the gripper is stuck")
    """)
    result = run_script(script)
    assert result.code == cli.EXIT_USER_RAISED
    [trace] = result.of_kind("traceback")
    assert isinstance(trace, str)
    assert trace.startswith("Traceback (most recent call last):")
    assert trace.rstrip().endswith("ValueError: the gripper is stuck")
    assert "armnet_runtime" not in trace  # the customer's frames only; stderr has them all
    assert f'File "{script}", line 6, in run' in trace
    assert "job job-42 will be marked FAILED" in result.stderr
    assert "ValueError: the gripper is stuck" in result.stderr
    assert result.of_kind("result") == []


def test_a_syntax_error_exits_4_with_a_traceback_marker(tmp_path: Path) -> None:
    script = write(tmp_path, "from armnet_runtime import main\n\n@main\ndef run(ctx:\n    pass\n")
    result = run_script(script)
    assert result.code == cli.EXIT_USER_IMPORT_FAILED
    [trace] = result.of_kind("traceback")
    assert "SyntaxError" in str(trace) and "importlib" not in str(trace)
    assert "failed to import user script" in result.stderr


def test_an_import_error_exits_4(tmp_path: Path) -> None:
    script = write(tmp_path, "import armnet_module_that_does_not_exist\n")
    result = run_script(script)
    assert result.code == cli.EXIT_USER_IMPORT_FAILED
    assert "armnet_module_that_does_not_exist" in str(result.of_kind("traceback"))


def test_no_main_exits_3(tmp_path: Path) -> None:
    script = write(tmp_path, "def run(ctx):\n    return 1\n")
    result = run_script(script)
    assert result.code == cli.EXIT_NO_MAIN
    assert "no @main-decorated function found" in result.stderr
    assert result.markers() == []


def test_two_mains_exit_4_naming_both(tmp_path: Path) -> None:
    script = write(tmp_path, """
        from armnet_runtime import main

        @main
        def first(ctx):
            return 1

        @main
        def second(ctx):
            return 2
    """)
    result = run_script(script)
    assert result.code == cli.EXIT_USER_IMPORT_FAILED
    [trace] = result.of_kind("traceback")
    assert "MainRegistrationError: armnet: multiple @main-decorated functions found" in str(trace)
    assert "already registered: __armnet_main__.first; new: __armnet_main__.second" in str(trace)


def test_missing_env_exits_5(tmp_path: Path) -> None:
    result = run_script(HELLO, env={"ARMNET_JOB_ID": "j", "ARMNET_LOCAL_CONTAINER": "1"})
    assert result.code == cli.EXIT_BAD_CONTEXT
    assert "failed to build context" in result.stderr
    assert "ARMNET_EMBODIMENT" in result.stderr


def test_a_malformed_cell_config_exits_5_naming_the_field() -> None:
    bad = json.dumps({"arms": {"left": {"robot_port": "/x", "safety_limt": 3}}})
    result = run_script(HELLO, env={**FAST_ENV, "ARMNET_CELL_CONFIG": bad})
    assert result.code == cli.EXIT_BAD_CONTEXT
    assert "arms.left.safety_limt: unknown field" in result.stderr


@pytest.mark.parametrize("argv", [[], ["a.py", "b.py"]])
def test_bad_usage_exits_2(argv: list[str]) -> None:
    result = run_script(HELLO, argv=argv)
    assert result.code == cli.EXIT_USAGE
    assert "usage: armnet-runtime SCRIPT" in result.stderr


def test_a_missing_script_exits_4(tmp_path: Path) -> None:
    result = run_script(tmp_path / "nope.py")
    assert result.code == cli.EXIT_USER_IMPORT_FAILED
    assert "does not exist" in result.stderr


def test_system_exit_passes_through(tmp_path: Path) -> None:
    script = write(tmp_path, """
        import sys
        from armnet_runtime import main

        @main
        def run(ctx):
            print("leaving")
            sys.exit(7)
    """)
    result = run_script(script)
    assert result.code == 7
    assert result.of_kind("traceback") == [] and result.of_kind("result") == []
    assert "leaving" in result.stdout


@pytest.mark.parametrize("ending", ["return 'done'", "raise RuntimeError('late')", "sys.exit(7)"])
def test_what_a_job_leaves_for_its_exit_still_happens_however_main_ends(tmp_path: Path, ending: str) -> None:
    """The runtime skips the interpreter's last collections at exit (``_wind_down_quickly``), not
    the job's own wind-down: its atexit handlers run and a module's unclosed file is flushed."""
    out = tmp_path / "out"
    script = write(tmp_path, f"""
        import atexit, sys
        from armnet_runtime import main

        OUT = {str(out)!r}
        LOG = open(OUT + ".log", "w")  # never closed: the interpreter flushes it at exit
        atexit.register(lambda: open(OUT + ".atexit", "w").write("ran"))

        @main
        def run(ctx):
            LOG.write("buffered, never flushed by the job")
            {ending}
    """)
    result = run_script(script)

    assert result.code in (0, 1, 7), result.stderr
    assert Path(f"{out}.log").read_text() == "buffered, never flushed by the job"
    assert Path(f"{out}.atexit").read_text() == "ran"


def test_the_script_directory_is_importable(tmp_path: Path) -> None:
    write(tmp_path, "VALUE = 'from a sibling'\n", name="helper_mod_for_armnet.py")
    script = write(tmp_path, """
        from armnet_runtime import main
        import helper_mod_for_armnet

        @main
        def run(ctx):
            return helper_mod_for_armnet.VALUE
    """)
    result = run_script(script)
    assert result.code == 0, result.stderr
    assert result.of_kind("result") == ["from a sibling"]


def test_none_return_prints_no_result_marker(tmp_path: Path) -> None:
    script = write(tmp_path, "from armnet_runtime import main\n\n@main\ndef run(ctx):\n    pass\n")
    result = run_script(script)
    assert result.code == 0
    assert result.markers() == []


def test_a_non_json_return_value_fails_clearly(tmp_path: Path) -> None:
    script = write(tmp_path, """
        from armnet_runtime import main

        @main
        def run(ctx):
            return {"when": object()}
    """)
    result = run_script(script)
    assert result.code == cli.EXIT_USER_RAISED
    assert "must be JSON-serialisable" in result.stderr
    assert "JSON-serialisable" in str(result.of_kind("traceback"))
    assert result.of_kind("result") == []


def test_reset_without_endpoint_prompts_through_the_runtime(tmp_path: Path) -> None:
    script = write(tmp_path, """
        from armnet_runtime import main

        @main
        def run(ctx):
            ctx.cell.reset()
            return "reset done"
    """)
    result = run_script(script, stdin="\n")
    assert result.code == 0, result.stderr
    assert "Z Reset the cell workspace, then press Enter. \n" in result.stdout
    assert result.of_kind("progress") == ["Waiting for workspace reset..."]
    assert result.of_kind("result") == ["reset done"]


def test_rerun_frames_are_written_before_the_result(tmp_path: Path) -> None:
    script = write(tmp_path, """
        import numpy as np
        from armnet_runtime import main

        @main
        def run(ctx):
            frame = np.zeros((48, 64, 3), dtype=np.uint8)
            for i in range(3):
                ctx.log_rerun_data({"front": frame, "state": np.array([1.0, 2.0])},
                                   {"shoulder_pan.pos": float(i)})
            return "sent"
    """)
    result = run_script(script, env={**FAST_ENV, "ARMNET_RERUN_QUEUE_MAXSIZE": "100"})
    assert result.code == 0, result.stderr
    kinds = [m.kind for m in result.markers()]
    assert kinds == ["rerun", "rerun", "rerun", "result"]
    packets = [decode_packet(p) for p in result.of_kind("rerun")]  # type: ignore[arg-type]
    assert [p.sequence for p in packets] == [0, 1, 2]
    assert {p.job_id for p in packets} == {"job-42"}
    last = {e.path: e for e in packets[-1].entries}
    assert last["action.shoulder_pan.pos"].scalar == 2.0
    assert (last["observation.state_0"].scalar, last["observation.state_1"].scalar) == (1.0, 2.0)
    image = last["observation.front"].image
    assert image is not None and image.encoding == ENCODING_JPEG
    assert (image.width, image.height, image.channels) == (64, 48, 3)


def test_run_in_process_twice_restores_the_callers_streams(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for key, value in FAST_ENV.items():
        monkeypatch.setenv(key, value)
    first = write(tmp_path, "from armnet_runtime import main\n\n@main\ndef a(ctx):\n    return 'a'\n",
                  name="first.py")
    second = write(tmp_path, "from armnet_runtime import main\n\n@main\ndef b(ctx):\n    return 'b'\n",
                   name="second.py")
    stdout_before = sys.stdout
    assert cli.run([str(first)]) == cli.EXIT_OK
    assert cli.run([str(second)]) == cli.EXIT_OK
    assert sys.stdout is stdout_before
    results = [parse_marker_line(line) for line in capsys.readouterr().out.splitlines()]
    assert [m.payload for m in results if m is not None and m.kind == "result"] == ["a", "b"]
