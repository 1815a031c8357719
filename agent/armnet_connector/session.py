"""Request handling for one connection on ``robot.sock`` or ``operator.sock``.

This module owns the ops of runtime/PROTOCOL.md: it validates each request's
fields, reaches real objects only through the allow-list, routes motion through
the guard, and turns every failure into a reply. It never reads or writes the
socket (``server`` does) and never raises out of ``handle``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from armnet_runtime.wire import decode, encode, plain_arguments

from . import __version__
from .allowlist import CLASSES, refusal
from .buscaps import cap_call, capped_parameters, first_capped
from .cell import CellState, RolloutEvent
from .errors import RequestError, bounded, failure_reply, not_allowed, protocol_error
from .frames import FrameAreas, FramePublisher
from .hardware import Handle, create_arx5, create_camera, create_feetech
from .introspection import answer as answer_outside_allowlist
from .retry import is_read, is_retried, with_read_retry
from .servo_trace import TRACED_METHODS, trace_call

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 1
MAX_OBJECTS_PER_CONNECTION = 256

Reply = dict[str, Any]


def _field(request: dict[str, Any], name: str, kind: type, *, default: Any = ...) -> Any:
    value = request.get(name, default)
    if value is ...:
        raise protocol_error(f"request field {name!r} is required")
    if default is not ... and value is default:
        return value
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise protocol_error(f"request field {name!r} must be a {kind.__name__}, got {type(value).__name__}")
    return value


MAX_ROLLOUTS = 1_000_000


def _rollout_count(request: dict[str, Any], name: str) -> int | None:
    """A rollout index or total: a count a person can read (0..MAX_ROLLOUTS), or absent."""
    value: int | None = _field(request, name, int, default=None)
    if value is not None and not 0 <= value <= MAX_ROLLOUTS:
        raise protocol_error(f"rollout {name} must be between 0 and {MAX_ROLLOUTS:,}, got {str(value)[:32]}")
    return value


def _decoded(value: Any, what: str) -> Any:
    try:
        return decode(value)
    except Exception as exc:  # noqa: BLE001 — hostile nesting and malformed tags alike are the client's fault
        raise protocol_error(f"{what} is not valid tagged JSON: {exc}") from None


def _arguments(request: dict[str, Any]) -> tuple[list[Any], dict[str, Any]]:
    """The call's decoded positional and keyword arguments (``args``/``kwargs``, both optional).

    ``op_call`` takes a control loop's call (``plain_arguments``, no keywords) as parsed
    before it comes here.
    """
    args = _decoded(_field(request, "args", list, default=[]), "args")
    kwargs = _decoded(_field(request, "kwargs", dict, default={}), "kwargs")
    if type(args) is not list or type(kwargs) is not dict or (kwargs and not all(type(k) is str for k in kwargs)):
        raise protocol_error("args must be a list and kwargs an object with string keys")
    return args, kwargs


_ABSENT: Any = object()


def _encoded(value: Any, what: str) -> Any:
    try:
        return encode(value)
    except Exception as exc:  # noqa: BLE001 — any unencodable value is the method's, not ours
        raise RequestError("TypeError", f"{what} returned a value that cannot cross the socket: {exc}") from None


class Session:
    """One connection's state; ``handle`` answers every request with a reply dict."""

    socket_name = ""

    def __init__(self, cell: CellState) -> None:
        self.cell = cell
        self.ops: dict[str, Callable[[dict[str, Any]], Reply]] = {"hello": self.op_hello}

    def handle(self, request: dict[str, Any]) -> Reply:
        self.cell.counters.requests += 1
        try:
            op = request.get("op")
            if not isinstance(op, str):
                raise protocol_error("a request needs a string 'op'")
            handler = self.ops.get(op)
            if handler is None:
                raise RequestError(
                    "UnknownOp", f"op {op[:64]!r} is not served on {self.socket_name}.sock; ops: {sorted(self.ops)}"
                )
            return handler(request)
        except Exception as exc:  # noqa: BLE001 — every failure becomes a reply; the connection stays usable
            self.cell.counters.errors += 1
            if not isinstance(exc, RequestError):
                log.info("%s request failed: %s: %s", self.socket_name, type(exc).__name__, bounded(str(exc)))
            return failure_reply(exc)

    def op_hello(self, request: dict[str, Any]) -> Reply:
        return {
            "ok": True, "protocol": PROTOCOL_VERSION,
            "server": f"armnet-connector/{__version__}", "socket": self.socket_name,
        }

    def close(self) -> None:
        """The client went away."""


@dataclass
class _Context:
    """A context manager a call returned, driven by ``enter``/``exit``."""

    parent: Handle
    enter: Callable[[], Any]
    exit: Callable[[BaseException | None], bool]


@dataclass(frozen=True, slots=True)
class _CallPlan:
    """The per-(object, method) facts of ``call`` that never change (see ``RobotSession._call_plan``)."""

    handle: Handle
    #: A lost servo reply is asked again (``retry.is_retried``: reads and acknowledged absolute writes).
    retried: bool
    camera: bool
    frame_read: bool
    #: The method's parameter names when some are capped (``buscaps``), else ``()``.
    capped: tuple[str, ...] = ()
    #: Calls with at most this many positional arguments and no keyword ones pass no capped value.
    capped_from: int = 0
    #: A bus's ``disconnect``: the job lets go of the arm (``CellState.bus_let_go``).
    lets_go: bool = False
    #: A bus call whose positions go to the cell's servo trace (``servo_trace.trace_call``): its arm.
    trace_arm: str | None = None


class RobotSession(Session):
    socket_name = "robot"

    def __init__(self, cell: CellState, frames: FrameAreas | None = None) -> None:
        super().__init__(cell)
        self.objects: dict[str, Handle | _Context] = {}
        self._counter = 0
        self._frame_areas = frames
        self._publishers: dict[int, FramePublisher] = {}
        self._plans: dict[tuple[str, str], _CallPlan] = {}
        self.ops.update(
            create=self.op_create, getattr=self.op_getattr, setattr=self.op_setattr, call=self.op_call,
            enter=self.op_enter, exit=self.op_exit, close=self.op_close,
            return_to_rest=self.op_return_to_rest, is_complete=self.op_is_complete,
        )

    def _add(self, prefix: str, item: Handle | _Context) -> str:
        if len(self.objects) >= MAX_OBJECTS_PER_CONNECTION:
            raise not_allowed(f"a connection may hold at most {MAX_OBJECTS_PER_CONNECTION} objects; close some")
        self._counter += 1
        object_id = f"{prefix}{self._counter}"
        self.objects[object_id] = item
        return object_id

    def _lookup(self, request: dict[str, Any]) -> Handle | _Context:
        object_id = _field(request, "object_id", str)
        item = self.objects.get(object_id)
        if item is None:
            raise RequestError("UnknownObject", f"object {object_id[:64]!r} is not a live object of this connection")
        return item

    def _handle(self, request: dict[str, Any]) -> Handle:
        item = self._lookup(request)
        if not isinstance(item, Handle):
            raise RequestError("UnknownObject", "this object is a context manager: use enter/exit")
        return item

    def _context(self, request: dict[str, Any]) -> _Context:
        item = self._lookup(request)
        if not isinstance(item, _Context):
            raise RequestError("UnknownObject", "this object is not a context manager")
        return item

    # -- objects ------------------------------------------------------------------

    def op_create(self, request: dict[str, Any]) -> Reply:
        class_name = _field(request, "class", str)
        if class_name not in CLASSES:
            raise not_allowed(refusal(class_name, "", kind="call") or "")
        args, kwargs = _arguments(request)
        cell = self.cell
        if class_name == "FeetechMotorsBus":
            handle = create_feetech(
                args, kwargs, cell.config, cell.locks, cell.ranges, interlock=cell.interlock, recorder=cell.guard.recorder,
                end_recording=cell.inputs_end_recording, on_lost_reply=cell.count_bus_retry,
                ledger_for=cell.ledger,
            )
        elif class_name == "OpenCVCamera":
            assert cell.camera_factory is not None
            handle = create_camera(args, kwargs, cell.config, cell.locks, cell.camera_factory)
        else:
            handle = create_arx5(args, kwargs, cell.locks)
        object_id = self._add("o", handle)
        cell.register(handle)
        if class_name == "OpenCVCamera":
            self._attach_frames(handle)
        return {"ok": True, "object_id": object_id}

    def op_getattr(self, request: dict[str, Any]) -> Reply:
        handle = self._handle(request)
        name = _field(request, "name", str)
        why = refusal(handle.class_name, name, kind="get")
        if why is not None:
            return answer_outside_allowlist(handle, name, why)
        if name in CLASSES[handle.class_name].methods:
            return {"ok": True, "callable": True}
        if name in handle.overrides:
            value = handle.overrides[name]
        else:
            with handle.lock:
                if is_read(handle.class_name, name, kind="get"):
                    value = with_read_retry(handle, name, lambda: getattr(handle.obj, name), on_retry=self.cell.count_bus_retry)
                else:
                    value = getattr(handle.obj, name)
        return {"ok": True, "callable": False, "value": _encoded(value, name)}

    def op_setattr(self, request: dict[str, Any]) -> Reply:
        handle = self._handle(request)
        name = _field(request, "name", str)
        why = refusal(handle.class_name, name, kind="set")
        if why is not None:
            raise not_allowed(why)
        if "value" not in request:
            raise protocol_error("setattr needs a 'value'")
        value = _decoded(request["value"], "value")
        with handle.lock:
            setattr(handle.obj, name, value)
        return {"ok": True}

    def _call_plan(self, request: dict[str, Any]) -> _CallPlan:
        """What a call on (object, method) involves, checked once and reused for the same pair.

        A control loop repeats the same few calls; the lookup, the allow-list
        decision and the read/camera flags depend only on the pair, so later
        calls pay one dict lookup. Object ids are never reused, and a plan goes
        when its object is closed. The safety check is not part of a plan: it
        runs on every call.
        """
        object_id, method = request.get("object_id"), request.get("method")
        if type(object_id) is str and type(method) is str:
            plan = self._plans.get((object_id, method))
            if plan is not None:
                return plan
        handle = self._handle(request)
        method = _field(request, "method", str)
        why = refusal(handle.class_name, method, kind="call")
        if why is not None:
            raise not_allowed(why)
        camera = handle.class_name == "OpenCVCamera"
        capped = capped_parameters(handle.class_name, getattr(handle.obj, method, None))
        plan = _CallPlan(
            handle, is_retried(handle.class_name, method), camera, camera and method in FRAME_READS,
            capped, first_capped(handle.class_name, capped),
            lets_go=handle.class_name == "FeetechMotorsBus" and method == "disconnect",
            trace_arm=handle.arm if handle.class_name == "FeetechMotorsBus" and method in TRACED_METHODS else None,
        )
        if len(self._plans) < MAX_OBJECTS_PER_CONNECTION * 4:
            self._plans[(request["object_id"], method)] = plan
        return plan

    def op_call(self, request: dict[str, Any]) -> Reply:
        plan = self._call_plan(request)
        handle, method, camera = plan.handle, request["method"], plan.camera
        args, kwargs = request.get("args", _ABSENT), request.get("kwargs", _ABSENT)
        if type(args) is list and (kwargs is _ABSENT or (type(kwargs) is dict and not kwargs)) and plain_arguments(args):
            kwargs = {}  # a control loop's call is its own decoding: used as parsed, no copy, no per-item step
        else:
            args, kwargs = _arguments(request)
        if plan.capped and (kwargs or len(args) > plan.capped_from):
            capped = cap_call(handle.class_name, plan.capped, args, kwargs)
            if capped.lowered:
                self.cell.counters.calls_capped += 1
            args, kwargs = capped.args, capped.kwargs
        shared_frame = plan.frame_read and _wants_shared_frame(request)
        if camera and method == "disconnect":
            self._frames_connected(handle, False)  # first: the SDK stops serving frames locally at once
        try:
            with handle.lock:
                self.cell.guard.check(handle, method, args, kwargs)
                self.cell.guard.recorder.record_device_call()
                if method == "torque_disabled":
                    return self._torque_disabled(handle, args, kwargs)
                bound = getattr(handle.obj, method)
                if plan.retried:
                    result = with_read_retry(
                        handle, method, lambda: bound(*args, **kwargs), on_retry=self.cell.count_bus_retry,
                        before_retry=lambda: self.cell.guard.check(handle, method, args, kwargs),
                    )
                else:
                    result = bound(*args, **kwargs)
                if method == "sync_read":
                    self.cell.guard.remember_present(handle, args, kwargs, result)
                if plan.trace_arm is not None and self.cell.servo_trace is not None:
                    trace_call(self.cell.servo_trace, plan.trace_arm, method, args, kwargs, result)
        finally:
            if plan.lets_go:  # the job's own disconnect, even one that failed half-way
                self.cell.bus_let_go(handle)
        if camera and method == "connect":
            self._frames_connected(handle, True)
        if result is None and not shared_frame:
            return {"ok": True, "value": None}  # a write's reply: nothing to encode
        if type(result) is not dict and _is_context_manager(result):
            context = _Context(handle, result.__enter__, lambda exc: bool(result.__exit__(
                type(exc) if exc else None, exc, None)))
            return {"ok": True, "context_manager": True, "object_id": self._add("c", context)}
        if shared_frame:
            frame = self._publish(handle, result)
            if frame is not None:
                return {"ok": True, "frame": frame}
        return {"ok": True, "value": _encoded(result, method)}

    # -- camera frames through shared memory (frames.py; runtime/PROTOCOL.md) ----------

    def _attach_frames(self, handle: Handle) -> None:
        """A publisher for a new camera object: its capture thread publishes every frame."""
        if self._frame_areas is None:
            return
        publisher = self._frame_areas.publisher(str(handle.overrides.get("index_or_path", "")))
        if self.cell.camera_video is not None and handle.camera is not None:
            publisher.tap = self.cell.camera_video.tap(handle.camera)
        publisher.attach(handle.obj)
        self._publishers[id(handle)] = publisher

    def _frames_connected(self, handle: Handle, connected: bool) -> None:
        publisher = self._publishers.get(id(handle))
        if publisher is not None:
            publisher.set_connected(connected and bool(handle.obj.is_connected))

    def _publish(self, handle: Handle, frame: Any) -> dict[str, Any] | None:
        """The frame a read returned, written to the handle's area, as a descriptor; None: send it inline."""
        publisher = self._publishers.get(id(handle))
        if publisher is None:
            return None
        stamp = getattr(handle.obj, "latest_timestamp", None)
        return publisher.publish(frame, stamp if isinstance(stamp, float) else None)

    def _forget_frames(self, handle: Handle) -> None:
        publisher = self._publishers.pop(id(handle), None)
        if publisher is not None:
            publisher.close()

    def _torque_disabled(self, handle: Handle, args: list[Any], kwargs: dict[str, Any]) -> Reply:
        # Driven here as disable/enable calls rather than LeRobot's generator, so that the
        # re-enable at exit is refused once the interlock holds (the arm stays released).
        if len(args) > 1 or set(kwargs) - {"motors"}:
            raise RequestError("TypeError", "torque_disabled(motors=None) takes one optional argument")
        motors = args[0] if args else kwargs.get("motors")
        bus = handle.obj
        switch_args = [motors] if motors is not None else []

        # Each switch is the same acknowledged absolute write as a direct disable/enable_torque
        # call, and so is asked again on a lost acknowledgement (a loaded host failed LeRobot's
        # SO follower in connect -> configure -> torque_disabled), checked again before each retry.
        def switch(method: str) -> None:
            with_read_retry(handle, method, lambda: getattr(bus, method)(motors), on_retry=self.cell.count_bus_retry,
                            before_retry=lambda: self.cell.guard.check(handle, method, switch_args, {}))

        def enter() -> None:
            with handle.lock:
                switch("disable_torque")

        def leave(exc: BaseException | None) -> bool:
            with handle.lock:
                if self.cell.interlock.tripped:
                    log.warning("torque_disabled exit: the interlock holds, torque stays off")
                else:
                    switch("enable_torque")
            return False

        return {"ok": True, "context_manager": True, "object_id": self._add("c", _Context(handle, enter, leave))}

    def op_enter(self, request: dict[str, Any]) -> Reply:
        context = self._context(request)
        with context.parent.lock:
            value = context.enter()
        return {"ok": True, "value": _encoded(value, "__enter__")}

    def op_exit(self, request: dict[str, Any]) -> Reply:
        object_id = _field(request, "object_id", str)
        context = self._context(request)
        exc_type = _field(request, "exc_type", str, default=None)
        exc_message = _field(request, "exc_message", str, default=None)
        exc = _client_exception(exc_type, exc_message) if exc_type else None
        self.objects.pop(object_id, None)
        with context.parent.lock:
            suppress = context.exit(exc)
        return {"ok": True, "suppress": bool(suppress)}

    def op_close(self, request: dict[str, Any]) -> Reply:
        object_id = _field(request, "object_id", str)
        item = self._lookup(request)
        del self.objects[object_id]
        if isinstance(item, Handle):
            self._plans = {key: plan for key, plan in self._plans.items() if plan.handle is not item}
            self.cell.release(item)
            self._forget_frames(item)
        return {"ok": True}

    def op_return_to_rest(self, request: dict[str, Any]) -> Reply:
        self.cell.return_to_rest()
        return {"ok": True}

    def op_is_complete(self, request: dict[str, Any]) -> Reply:
        block = _field(request, "block", bool, default=False)
        complete, success = self.cell.completion.is_complete(block=bool(block))
        if complete:
            self.cell.record_monitor_verdict(told_complete=True)
        return {"ok": True, "complete": bool(complete), "success": bool(success)}

    def close(self) -> None:
        handles = [item for item in self.objects.values() if isinstance(item, Handle)]
        self.objects.clear()
        self._plans.clear()
        for handle in handles:
            self.cell.release(handle)
            self._forget_frames(handle)


_CLIENT_EXCEPTIONS: dict[str, type[Exception]] = {
    cls.__name__: cls
    for cls in (
        ValueError, RuntimeError, KeyError, TypeError, TimeoutError, ConnectionError,
        OSError, IndexError, AttributeError,
    )
}


def _client_exception(exc_type: str, message: str | None) -> Exception:
    """The exception the client's ``with`` body raised, rebuilt from its name (never imported)."""
    cls = _CLIENT_EXCEPTIONS.get(exc_type, Exception)
    return cls(message or exc_type)


FRAME_READS = frozenset({"read", "async_read", "read_latest"})
"""Camera methods whose frame may travel through the frame area instead of the reply."""


def _wants_shared_frame(request: dict[str, Any]) -> bool:
    """The request's ``frames`` field: ``"shm"`` (descriptor), absent or ``"inline"`` (pixels in the reply)."""
    mode = request.get("frames", "inline")
    if mode == "shm":
        return True
    if mode == "inline":
        return False
    raise protocol_error(f"request field 'frames' must be 'shm' or 'inline', got {str(mode)[:32]!r}")


def _is_context_manager(value: Any) -> bool:
    kind = type(value)
    return hasattr(kind, "__enter__") and hasattr(kind, "__exit__")


class OperatorSession(Session):
    socket_name = "operator"

    def __init__(self, cell: CellState) -> None:
        super().__init__(cell)
        self.ops.update(
            reset=self.op_reset, get_teleop=self.op_get_teleop, get_teleop_event=self.op_get_teleop_event,
            rollout_begin=self.op_rollout_begin, rollout_end=self.op_rollout_end,
            get_completion=self.op_get_completion, shutdown_status=self.op_shutdown_status,
            should_stop=self.op_should_stop,
        )

    def op_reset(self, request: dict[str, Any]) -> Reply:
        self.cell.reset()
        return {"ok": True}

    def op_get_teleop(self, request: dict[str, Any]) -> Reply:
        return {"ok": True, "action": _encoded(self.cell.inputs.latest_teleop_action(), "get_teleop")}

    def op_get_teleop_event(self, request: dict[str, Any]) -> Reply:
        return {"ok": True, "event": self.cell.inputs.next_teleop_event()}

    def op_rollout_begin(self, request: dict[str, Any]) -> Reply:
        index = _rollout_count(request, "index")
        total = _rollout_count(request, "total")
        controls = _field(request, "outcome_controls", bool, default=None)
        self.cell.record_rollout(RolloutEvent("begin", self.cell.now(), index, total, controls))
        return {"ok": True}

    def op_rollout_end(self, request: dict[str, Any]) -> Reply:
        self.cell.record_monitor_verdict(told_complete=False)
        self.cell.record_rollout(RolloutEvent("end", self.cell.now()))
        return {"ok": True}

    def op_get_completion(self, request: dict[str, Any]) -> Reply:
        outcome = self.cell.inputs.take_outcome()
        if outcome is not None:
            self.cell.trace_event("operator_verdict", detail="success" if outcome else "failure")
        return {"ok": True, "reported": outcome is not None, "success": bool(outcome)}

    def op_shutdown_status(self, request: dict[str, Any]) -> Reply:
        deadline = self.cell.deadline
        return {
            "ok": True, "shutting_down": deadline.deadline_passed,
            "grace_remaining_s": deadline.grace_remaining_s(),
        }

    def op_should_stop(self, request: dict[str, Any]) -> Reply:
        return {"ok": True, "stop": self.cell.inputs.stop_requested()}
