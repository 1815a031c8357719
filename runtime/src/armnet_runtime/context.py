"""The job context handed to ``@main``: the job, its cell, its volume and secrets.

:func:`build_context` reads the env vars the platform injects (see
:mod:`armnet_runtime.env`) and the ``ARMNET_CELL_CONFIG`` document. :class:`Cell`
talks to the cell's connector over the JSON-lines protocol of
``runtime/PROTOCOL.md``. The polled ops used inside control loops never stall
or crash the loop: bounded reads, a dropped connection on any failure (the next
call reconnects), throttled warnings, and the neutral answer. Only the
standard library and pydantic are imported at module level.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Optional

from armnet_core.models import BIMANUAL_SO101_EMBODIMENT, SO101_EMBODIMENT, Embodiment, Task

from armnet_runtime import env as env_keys
from armnet_runtime.cell_config import CellConfig, build_camera_configs, parse_cell_config
from armnet_runtime.endpoints import looks_like_connector_endpoint, with_arm
from armnet_runtime.transport import REST_TIMEOUT_S, PersistentConnection, connector_request

logger = logging.getLogger(__name__)

__all__ = [
    "BIMANUAL_SO101_EMBODIMENT",
    "SO101_EMBODIMENT",
    "BimanualCalibrationLayout",
    "Cell",
    "CompletionStatus",
    "Context",
    "ResetTimeoutException",
    "RuntimeArm",
    "Volume",
    "build_context",
    "require_so101_embodiment",
]

_TELEOP_READ_TIMEOUT_S = 0.5
"""Bound on each polled read (teleop, completion, shutdown status): a control loop tick."""

_TELEOP_ERROR_LOG_INTERVAL_S = 5.0
"""At most one warning per interval per polled channel, so a dead connector cannot flood logs."""

_RESET_PROMPT = "Reset the cell workspace, then press Enter. "

# The connector helpers under the private names the SDK's documented implementation of these
# methods uses.
_TeleopConnection = PersistentConnection
_connector_request = connector_request
_looks_like_connector_endpoint = looks_like_connector_endpoint


class ResetTimeoutException(RuntimeError):
    """Raised by ``ctx.cell.reset()`` when no operator confirmed the reset in time.

    The cell has tripped its interlock by then (no further robot motion).
    Catch it to save what the job collected before letting it fail.
    """


class CompletionStatus(NamedTuple):
    """Result of :meth:`Cell.is_complete`: whether the episode is over, and whether it succeeded.

    ``bool(status)`` is ``status.complete`` so ``if ctx.cell.is_complete():`` works.
    """

    complete: bool
    success: bool

    def __bool__(self) -> bool:
        return self.complete


@dataclass
class Volume:
    """The user's volume mounted into the container; paths are relative and never escape it."""

    root: Optional[Path] = None

    def path(self, relative_path: str | Path) -> Path:
        if self.root is None:
            raise RuntimeError("armnet volume is not mounted in this context")
        rel = Path(relative_path)
        if rel.is_absolute() or ".." in rel.parts:
            raise ValueError("volume path must be relative and must not contain '..'")
        return self.root / rel

    def read_bytes(self, relative_path: str | Path) -> bytes:
        return self.path(relative_path).read_bytes()

    def read_text(self, relative_path: str | Path) -> str:
        return self.path(relative_path).read_text()

    def write_bytes(self, relative_path: str | Path, data: bytes) -> Path:
        path = self.path(relative_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        return path

    def write_text(self, relative_path: str | Path, data: str) -> Path:
        path = self.path(relative_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(data)
        return path


@dataclass(frozen=True)
class RuntimeArm:
    """One named arm of a multi-arm cell, as the job sees it."""

    name: str
    robot_port: str
    robot_id: Optional[str] = None
    calibration_dir: Optional[Path] = None
    calibration_file_path: Optional[Path] = None
    safety_limit: Optional[float] = None


@dataclass(frozen=True)
class BimanualCalibrationLayout:
    """A temporary calibration dir laid out as LeRobot's bimanual robots expect."""

    robot_id: str
    calibration_dir: Path


def _completion_from_response(response: dict[str, Any]) -> CompletionStatus:
    complete = bool(response.get("complete", False))
    return CompletionStatus(complete=complete, success=bool(response.get("success", complete)))


@dataclass
class Cell:
    """Handle to the robot cell the job runs on: its endpoints, arms, calibration and ops."""

    robot_port: Optional[str] = None
    """Robot port for LeRobot configs: the connector endpoint in a cell, a device path locally."""

    robot_id: Optional[str] = None
    """Stable robot id LeRobot uses to find calibration data."""

    calibration_dir: Optional[Path] = None
    """Calibration store path visible inside the container."""

    calibration_file_path: Optional[Path] = None
    """Exact LeRobot calibration file path visible inside the container."""

    language_instruction: Optional[str] = None
    """Task instruction provided by the cell."""

    local_control_endpoint: Optional[str] = None
    """Developer local-container control endpoint for keyboard-driven state."""

    operator_call_endpoint: Optional[str] = None
    """The cell's operator-call endpoint (reset confirmation, teleop, rollout, completion)."""

    is_local_container: bool = False
    """True when running an image locally with direct hardware."""

    safety_limit: Optional[float] = None
    """Relative action safety limit exposed by the cell, if applicable."""

    arms: dict[str, RuntimeArm] = field(default_factory=dict)
    """Named arms for bimanual/multi-arm cells."""

    _teleop_conn: Any = field(default=None, init=False, repr=False, compare=False)
    _teleop_last_error_log: float = field(default=0.0, init=False, repr=False, compare=False)
    _completion_conn: Any = field(default=None, init=False, repr=False, compare=False)
    _completion_last_error_log: float = field(default=0.0, init=False, repr=False, compare=False)
    _status_conn: Any = field(default=None, init=False, repr=False, compare=False)
    _status_last_error_log: float = field(default=0.0, init=False, repr=False, compare=False)

    @property
    def is_bimanual(self) -> bool:
        return {"left", "right"}.issubset(self.arms)

    def arm(self, name: str) -> RuntimeArm:
        try:
            return self.arms[name]
        except KeyError as exc:
            raise KeyError(f"cell has no arm named {name!r}") from exc

    def prepare_bimanual_calibration_dir(self) -> BimanualCalibrationLayout:
        """Copy each arm's calibration into a temp dir as ``<robot_id>_<left|right>.json``.

        An arm's source is its ``calibration_file_path``, else ``<robot_id>.json``
        in its own ``calibration_dir``, else in the cell-level ``calibration_dir``.
        """
        if not self.is_bimanual:
            raise RuntimeError("bimanual calibration requires left and right arms")
        robot_id = self.robot_id
        if not robot_id:
            raise RuntimeError("bimanual calibration requires ctx.cell.robot_id")
        sources: dict[str, Path] = {}
        for arm_name in ("left", "right"):
            arm = self.arm(arm_name)
            source = arm.calibration_file_path
            if source is None:
                base = arm.calibration_dir or self.calibration_dir
                if base is not None and arm.robot_id:
                    source = Path(base) / f"{arm.robot_id}.json"
            if source is None or not Path(source).is_file():
                raise RuntimeError(
                    f"no calibration file found for {arm_name} arm (robot_id={arm.robot_id!r}); "
                    f"looked for {source if source is not None else '<unresolved>'}. Set the "
                    "cell-level calibration_dir (with per-arm robot_id) or each arm's "
                    "calibration_dir/calibration_file_path."
                )
            sources[arm_name] = Path(source)
        target = Path(tempfile.mkdtemp(prefix="armnet-bimanual-calibration-"))
        for arm_name, source in sources.items():
            shutil.copy2(source, target / f"{robot_id}_{arm_name}.json")
        return BimanualCalibrationLayout(robot_id=robot_id, calibration_dir=target)

    def _operator_endpoint(self) -> Optional[str]:
        return self.operator_call_endpoint or self.local_control_endpoint

    def reset(self) -> None:
        """Return the robot to rest, then block until an operator confirms the workspace reset.

        The rest move goes to the robot connector; the confirmation to the
        operator endpoint, which waits as long as the cell's reset timeout
        allows (the connector bounds it, so the client sets no read timeout).
        With no operator endpoint (a bare local run) it prompts on the terminal.
        """
        self._report_progress("Waiting for workspace reset...")
        if self.robot_port and _looks_like_connector_endpoint(self.robot_port):
            response = _connector_request(self.robot_port, {"op": "return_to_rest"}, read_timeout=REST_TIMEOUT_S)
            if not response.get("ok"):
                raise RuntimeError(response.get("error", "robot return-to-rest failed"))
        endpoint = self._operator_endpoint()
        if endpoint:
            response = _connector_request(
                endpoint, {"op": "reset", "request": {"kind": "manual"}}, read_timeout=None
            )
            if not response.get("ok"):
                error = response.get("error", "operator reset confirmation failed")
                if response.get("error_type") == "ResetTimeoutException":
                    raise ResetTimeoutException(error)
                raise RuntimeError(error)
            return
        input(_RESET_PROMPT)

    def is_complete(self, *, block: bool = False) -> CompletionStatus:
        """Whether the current episode is over, and whether it succeeded.

        A human-reported outcome (operator success/fail) wins; otherwise the
        cell's completion monitor decides (``block=True`` waits for it to score
        the latest frames). Without any endpoint: not complete.
        """
        reported = self._human_completion()
        if reported is not None:
            return CompletionStatus(complete=True, success=reported)
        request = {"op": "is_complete", "block": block}
        if self.local_control_endpoint:
            response = _connector_request(self.local_control_endpoint, request)
            if not response.get("ok"):
                raise RuntimeError(response.get("error", "local completion check failed"))
            return _completion_from_response(response)
        if self.robot_port and _looks_like_connector_endpoint(self.robot_port):
            response = _connector_request(self.robot_port, request)
            if not response.get("ok"):
                raise RuntimeError(response.get("error", "cell completion check failed"))
            return _completion_from_response(response)
        return CompletionStatus(complete=False, success=False)

    def _polled_connection(self, attribute: str, endpoint: str) -> PersistentConnection:
        conn: Optional[PersistentConnection] = getattr(self, attribute)
        if conn is None or conn.endpoint != endpoint:
            if conn is not None:
                conn.close()
            conn = _TeleopConnection(endpoint, timeout=_TELEOP_READ_TIMEOUT_S)
            setattr(self, attribute, conn)
        return conn

    def _poll(
        self,
        channel: str,
        endpoint: Optional[str],
        payload: dict[str, Any],
        failure: str,
        *,
        refused: Optional[str] = None,
    ) -> Optional[dict[str, Any]]:
        """One bounded request on a polled channel (``teleop``, ``completion``, ``status``).

        Returns the reply when it is ``ok``, else ``None``: a control loop must
        never stall or crash on a poll, so the caller answers its neutral value.
        ``None`` also when there is no endpoint; when the request failed, after a
        throttled warning (``failure`` formatted with the endpoint and the
        error; the failed request closed the connection, so the next call
        reconnects); and when the connector refused, after the ``refused``
        warning (formatted with its error) if one is given.
        """
        if not endpoint:
            return None
        conn = self._polled_connection(f"_{channel}_conn", endpoint)
        try:
            response = conn.request(payload)
        except Exception as exc:  # noqa: BLE001 - a poll must never break the control loop
            self._warn_throttled(f"_{channel}_last_error_log", failure, endpoint, exc)
            return None
        if not response.get("ok"):
            if refused is not None:
                logger.warning(refused, response.get("error"))
            return None
        return response

    def _warn_throttled(self, stamp_attribute: str, message: str, *args: object) -> None:
        now = time.monotonic()
        last: float = getattr(self, stamp_attribute)
        if last == 0.0 or now - last >= _TELEOP_ERROR_LOG_INTERVAL_S:
            setattr(self, stamp_attribute, now)
            logger.warning(message, *args)

    def _human_completion(self) -> Optional[bool]:
        """The operator's reported success/fail, or ``None`` if none is pending or it can't be read."""
        response = self._poll(
            "completion",
            self._operator_endpoint(),
            {"op": "get_completion"},
            "completion read from %s failed (treating as not complete): %r",
        )
        if response is None or not response.get("reported"):
            return None
        return bool(response.get("success", False))

    def rollout_begin(
        self,
        *,
        index: Optional[int] = None,
        total: Optional[int] = None,
        outcome_controls: bool = True,
    ) -> None:
        """Tell the platform a rollout started (``index`` is 1-based); best-effort.

        ``outcome_controls=False`` hides the operator's success/fail buttons
        (progress-only loops such as data collection).
        """
        payload: dict[str, Any] = {"outcome_controls": bool(outcome_controls)}
        if index is not None:
            payload["index"] = int(index)
        if total is not None:
            payload["total"] = int(total)
        self._rollout_signal("rollout_begin", **payload)

    def rollout_end(self) -> None:
        """Tell the platform the current rollout has ended (hides the operator's buttons)."""
        self._rollout_signal("rollout_end")

    def _rollout_signal(self, op: str, **payload: Any) -> None:
        endpoint = self._operator_endpoint()
        if not endpoint:
            return
        try:
            response = _connector_request(endpoint, {"op": op, **payload})
        except Exception:  # noqa: BLE001 - rollout signalling is best-effort
            logger.warning("rollout signal %s to %s failed", op, endpoint, exc_info=True)
            return
        if not response.get("ok"):
            logger.warning("rollout signal %s refused: %s", op, response.get("error"))

    def is_shutting_down(self) -> bool:
        """True once the job is past its deadline (grace window); poll it and finalize.

        Returns False with no endpoint or when the status can't be read.
        """
        response = self._poll(
            "status",
            self._operator_endpoint(),
            {"op": "shutdown_status"},
            "shutdown status read from %s failed: %r",
        )
        return response is not None and bool(response.get("shutting_down"))

    def should_stop(self) -> bool:
        """True when local or remote control asks the job to stop safely.

        The local-control endpoint answers strictly (errors raise); the cell's
        operator endpoint is polled like the other loop ops (False on failure).
        """
        request = {"op": "should_stop"}
        if self.local_control_endpoint:
            response = _connector_request(self.local_control_endpoint, request)
            if not response.get("ok"):
                raise RuntimeError(response.get("error", "local stop check failed"))
            return bool(response.get("stop", False))
        if self.operator_call_endpoint:
            polled = self._poll(
                "status", self.operator_call_endpoint, request, "stop check on %s failed: %r"
            )
            return polled is not None and bool(polled.get("stop"))
        return False

    def get_teleop_action(self) -> Optional[dict[str, float]]:
        """The freshest teleoperation action (latest value wins), or ``None``.

        ``None`` when nothing was received yet, no endpoint is attached, or the
        channel failed (the loop holds position; the next call reconnects).
        """
        endpoint = self._operator_endpoint()
        response = self._poll(
            "teleop",
            endpoint,
            {"op": "get_teleop"},
            "teleop read from %s failed (holding position; will reconnect): %r",
            refused="teleop read returned error: %s",
        )
        if response is None:
            return None
        action = response.get("action")
        if not action or not isinstance(action, dict):
            return None
        try:
            return {str(key): float(value) for key, value in action.items()}
        except (TypeError, ValueError):
            self._warn_throttled(
                "_teleop_last_error_log", "teleop action from %s is not numeric: %r", endpoint, action
            )
            return None

    def get_teleop_event(self) -> Optional[str]:
        """The next pending recording event (FIFO, one per call), or ``None``.

        Events: ``next_episode``, ``rerecord_episode``, ``stop_recording``.
        """
        response = self._poll(
            "teleop",
            self._operator_endpoint(),
            {"op": "get_teleop_event"},
            "teleop event read from %s failed (will reconnect): %r",
            refused="teleop event read returned error: %s",
        )
        if response is None:
            return None
        event = response.get("event")
        return str(event) if event else None

    def _report_progress(self, message: str) -> None:
        from armnet_runtime.markers import format_progress
        from armnet_runtime.streams import emit_line

        emit_line(format_progress(message))
        time.sleep(0.01)


@dataclass
class Context:
    """Everything a ``@main``-decorated function needs from the platform."""

    job_id: str
    embodiment: Embodiment
    task: Task
    args: dict[str, Any] = field(default_factory=dict)
    cell: Cell = field(default_factory=Cell)
    camera_configs: dict[str, Any] = field(default_factory=dict)
    cache_home: Optional[Path] = None
    volume: Volume = field(default_factory=Volume)
    secrets: dict[str, str] = field(default_factory=dict)
    timeout_seconds: Optional[int] = None
    _rerun_streamer: Any = field(default=None, init=False, repr=False, compare=False)

    def report_progress(self, message: str) -> None:
        """Surface a progress message: a marker line on stdout that the agent publishes."""
        from armnet_runtime.markers import format_progress
        from armnet_runtime.streams import emit_line

        emit_line(format_progress(message))

    def is_shutting_down(self) -> bool:
        """Whether the job is in its post-deadline grace window (see :meth:`Cell.is_shutting_down`)."""
        return self.cell.is_shutting_down()

    def log_rerun_data(
        self,
        observation: dict[str, Any] | None = None,
        action: dict[str, Any] | None = None,
        *,
        compress_images: bool = True,
        jpeg_quality: int = 75,
    ) -> None:
        """Stream observation/action data to the client's Rerun viewer, without blocking.

        A background worker encodes a packet (``rerun_packet.proto``; images as
        JPEG unless ``compress_images=False``) and prints it behind the Rerun
        marker. Its queue is bounded and drops the oldest frame under
        backpressure (``ARMNET_RERUN_QUEUE_MAXSIZE``).
        """
        if not observation and not action:
            return
        from armnet_runtime.rerun import RerunStreamer

        if self._rerun_streamer is None:
            self._rerun_streamer = RerunStreamer(self.job_id)
            self._rerun_streamer.start()
        self._rerun_streamer.submit(
            observation, action, compress_images=compress_images, jpeg_quality=jpeg_quality
        )


def require_so101_embodiment(ctx: Context, runtime_name: str) -> bool:
    """Check the job is a single or bimanual SO-101; True for bimanual.

    Raises ``NotImplementedError`` for another embodiment and ``RuntimeError``
    when the embodiment's arm count disagrees with the cell's arms.
    """
    if ctx.embodiment not in (SO101_EMBODIMENT, BIMANUAL_SO101_EMBODIMENT):
        raise NotImplementedError(
            f"{runtime_name} supports {SO101_EMBODIMENT!r} and "
            f"{BIMANUAL_SO101_EMBODIMENT!r}, got {ctx.embodiment!r}"
        )
    expect_bimanual = ctx.embodiment == BIMANUAL_SO101_EMBODIMENT
    if expect_bimanual != ctx.cell.is_bimanual:
        wanted = "two arms (left+right)" if expect_bimanual else "a single arm"
        raise RuntimeError(
            f"embodiment {ctx.embodiment!r} expects {wanted}, "
            f"but the cell exposes arms={sorted(ctx.cell.arms)}"
        )
    return expect_bimanual


def _load_cell_config() -> Optional[CellConfig]:
    raw = os.environ.get(env_keys.CELL_CONFIG)
    if not raw or not raw.strip():
        return None
    return parse_cell_config(raw)


def _path_from_env_or_config(key: str, configured: Optional[str]) -> Optional[Path]:
    value = os.environ.get(key) or configured
    return Path(value) if value else None


def _cell_safety_limit(config: Optional[CellConfig], embodiment: str) -> Optional[float]:
    return config.cell_safety_limit(embodiment) if config else None


def _build_runtime_arms(
    config: Optional[CellConfig], robot_endpoint: Optional[str] = None, embodiment: str = ""
) -> dict[str, RuntimeArm]:
    """Per-arm handles; an arm without its own port selects itself on the cell's endpoint."""
    if config is None:
        return {}
    arms: dict[str, RuntimeArm] = {}
    for name, arm in config.arms.items():
        port = arm.robot_port
        if port is None and robot_endpoint and looks_like_connector_endpoint(robot_endpoint):
            port = with_arm(robot_endpoint, name)
        if port is None:
            raise RuntimeError(
                f"ARMNET_CELL_CONFIG is invalid: arms.{name}.robot_port is required when the cell "
                "has no connector endpoint to select the arm on"
            )
        arms[name] = RuntimeArm(
            name=name,
            robot_port=port,
            robot_id=arm.robot_id,
            calibration_dir=Path(arm.calibration_dir) if arm.calibration_dir else None,
            calibration_file_path=(
                Path(arm.calibration_file_path) if arm.calibration_file_path else None
            ),
            safety_limit=config.arm_safety_limit(name, embodiment),
        )
    return arms


def _load_secrets() -> dict[str, str]:
    """Resolve ``ARMNET_SECRETS`` (a JSON list of env var names) to ``{name: value}``."""
    raw = os.environ.get(env_keys.SECRETS)
    if raw is None or not raw.strip():
        return {}
    hint = f'{env_keys.SECRETS} must be a JSON list of environment variable names, e.g. ["HF_TOKEN"]'
    try:
        names = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise RuntimeError(f"{hint}; it is not valid JSON: {exc}") from exc
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        raise RuntimeError(f"{hint}; got {type(names).__name__} {raw[:80]!r}")
    missing = [name for name in names if name not in os.environ]
    if missing:
        raise RuntimeError(
            f"secret env var(s) {', '.join(missing)} listed in {env_keys.SECRETS} are not set; "
            "check the job's secrets and that the Secrets exist in the job's namespace"
        )
    return {name: os.environ[name] for name in names}


def _timeout_from_env() -> Optional[int]:
    raw = os.environ.get(env_keys.TIMEOUT_SECONDS)
    return int(raw) if raw and raw.isdigit() else None


def _args_from_env() -> dict[str, Any]:
    raw = os.environ.get(env_keys.ARGS, "{}")
    try:
        args = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise RuntimeError(f"{env_keys.ARGS} env var is not valid JSON: {exc}") from exc
    if not isinstance(args, dict):
        raise RuntimeError(
            f"{env_keys.ARGS} must decode to a JSON object (dict); got {type(args).__name__}."
        )
    return args


def build_context() -> Context:
    """Build the :class:`Context` from the platform's env vars and ``ARMNET_CELL_CONFIG``.

    Raises ``RuntimeError`` (or :class:`~armnet_runtime.cell_config.CellConfigError`,
    a ``ValueError``) with a message naming the missing variable or bad field.
    """
    job_id = os.environ.get(env_keys.JOB_ID)
    embodiment = os.environ.get(env_keys.EMBODIMENT)
    task = os.environ.get(env_keys.TASK)
    if not job_id or not embodiment or not task:
        raise RuntimeError(
            "armnet runtime env vars not set; this program is meant to be executed inside an "
            "armnet cell container. Missing one of: "
            f"{env_keys.JOB_ID}, {env_keys.EMBODIMENT}, {env_keys.TASK}."
        )
    args = _args_from_env()
    config = _load_cell_config()
    robot_port = (
        os.environ.get(env_keys.CELL_SOCKET)
        or (config.robot_connector_endpoint if config else None)
        or (config.connector_socket_path if config else None)
        or (config.robot_port if config else None)
    )
    cell = Cell(
        robot_port=robot_port,
        operator_call_endpoint=(
            os.environ.get(env_keys.OPERATOR_CALL_ENDPOINT)
            or (config.operator_call_endpoint if config else None)
        ),
        robot_id=os.environ.get(env_keys.ROBOT_ID) or (config.robot_id if config else None),
        calibration_dir=_path_from_env_or_config(
            env_keys.CALIBRATION_DIR, config.calibration_dir if config else None
        ),
        calibration_file_path=_path_from_env_or_config(
            env_keys.CALIBRATION_FILE_PATH, config.calibration_file_path if config else None
        ),
        language_instruction=config.language_instruction if config else None,
        local_control_endpoint=os.environ.get(env_keys.LOCAL_CONTROL_ENDPOINT),
        is_local_container=bool(os.environ.get(env_keys.LOCAL_CONTAINER)),
        safety_limit=_cell_safety_limit(config, embodiment),
        arms=_build_runtime_arms(config, robot_port, embodiment),
    )
    return Context(
        job_id=job_id,
        embodiment=embodiment,
        task=task,
        args=args,
        cell=cell,
        camera_configs=build_camera_configs(config.camera_configs if config else {}),
        cache_home=_path_from_env_or_config(env_keys.CACHE_HOME, None),
        volume=Volume(root=_path_from_env_or_config(env_keys.VOLUME_HOME, None)),
        secrets=_load_secrets(),
        timeout_seconds=_timeout_from_env(),
    )
