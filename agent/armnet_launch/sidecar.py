"""The connector sidecar of a job pod: ``python -m armnet_launch.sidecar``.

The pod launcher puts the whole configuration in one env var
(``pod_spec.SIDECAR_ENV``): the connector config (ports are the devices the
pod mounts into this container only), the calibration files to write into the
shared calibration volume, and the job's deadline (the connector runs the
job's clock itself in a pod: the agent cannot call into it).

Two facts of native sidecars shape this module:

- the kubelet restarts a sidecar that dies, even with ``restartPolicy: Never``.
  A connector that comes back mid-job has lost its view of the arm, so the
  first start leaves a marker in the sockets volume (which outlives container
  restarts) and a later start trips the interlock at once: no motion resumes
  silently; the agent also sees the restart count and fails the job;
- the agent reads the connector's account of the job from this container's
  log: at stop the sidecar prints one ``RECORD_MARKER`` line with it.

A simulated cell's simulator normally runs in the agent, which hands its ptys to
this container as devices. An agent that runs in a pod itself (the Helm chart)
cannot: its ptys live in its own container's ``/dev/pts``, which no other
container can mount. Then the config names the preset (``simulator``) and this
sidecar runs the simulator next to the connector, on ptys of its own.

While the job runs, the agent reads the telemetry and rollout events of the
connector through ``observer.sock`` (``connector.observer``), and sends the cell
operator's inputs and the cancel notice through ``agent.sock``
(``connector.agent_inputs``), both served in a volume only this container
mounts; a restarted sidecar serves them anew in the same place.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

RECORD_MARKER = "ARMNET_CONNECTOR_RECORD "
STARTED_MARKER = ".connector-started"
RESTARTED_MESSAGE = (
    "the connector restarted while the job ran; its view of the arm was lost, so it refuses motion for the rest of "
    "the job"
)
SIGNAL_POLL_S = 0.1
#: The last rollout events in the record: the agent's polls of the observer socket may miss the final
#: ones (the job ends a rollout and exits; the kubelet stops this sidecar a second later). One log line
#: stays under the runtime's 16 KiB line split.
RECORD_ROLLOUT_EVENTS = 64


@dataclass(frozen=True)
class SidecarConfig:
    connector: Mapping[str, Any]
    socket_dir: str
    #: Calibration file path -> its JSON content.
    calibration: Mapping[str, Any]
    #: A simulated cell whose simulator this sidecar runs: ``{"preset": ..., "latency_ms": ...}``, else None.
    simulator: Mapping[str, Any] | None = None
    #: Where the read-only observer socket is served for the agent (a volume of this container only), or None.
    observer_dir: str | None = None
    #: The cell's record of the job on the host (the rollouts' pictures), mounted in this container only, or None.
    record_dir: str | None = None

    def as_data(self) -> dict[str, Any]:
        data: dict[str, Any] = {"connector": dict(self.connector), "socket_dir": self.socket_dir,
                                "calibration": dict(self.calibration), "observer_dir": self.observer_dir,
                                "record_dir": self.record_dir}
        if self.simulator is not None:
            data["simulator"] = dict(self.simulator)
        return data

    @classmethod
    def from_data(cls, data: Mapping[str, Any]) -> SidecarConfig:
        return cls(connector=data["connector"], socket_dir=data["socket_dir"], calibration=data.get("calibration", {}),
                   simulator=data.get("simulator"), observer_dir=data.get("observer_dir"),
                   record_dir=data.get("record_dir"))


def record_line(record: Mapping[str, Any]) -> str:
    return RECORD_MARKER + json.dumps(record, sort_keys=True, default=str)


def parse_record(log_text: str) -> dict[str, Any] | None:
    """The last record line of a connector log (a restarted connector prints one per life)."""
    found: dict[str, Any] | None = None
    for line in log_text.splitlines():
        if line.startswith(RECORD_MARKER):
            try:
                value = json.loads(line[len(RECORD_MARKER):])
            except ValueError:
                continue
            if isinstance(value, dict):
                found = value
    return found


def main() -> int:
    # First, before the slow imports: a stop that comes while this sidecar is still starting (the
    # job ended meanwhile) ends it after its record line, not by SIGTERM's default mid-import.
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    from armnet_connector import Connector, ConnectorConfig
    from armnet_connector.fast_exit import exit_after_clean_stop
    from armnet_connector.interlock import TripReason
    from armnet_connector.warm_imports import import_before_threads

    import_before_threads()  # before the connector's threads (warm_imports.py)

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    from armnet_launch.pod_spec import SIDECAR_ENV

    config = SidecarConfig.from_data(json.loads(os.environ[SIDECAR_ENV]))
    for path, content in config.calibration.items():
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(content, indent=2))
    socket_dir = Path(config.socket_dir)
    socket_dir.mkdir(parents=True, exist_ok=True)
    marker = socket_dir / STARTED_MARKER
    restarted = marker.exists()
    marker.touch()
    connector_config = ConnectorConfig.model_validate(dict(config.connector))
    sim = _start_simulator(config.simulator, connector_config) if config.simulator is not None else None
    if sim is not None:
        from armnet_connector.hardware import simulated_camera_factory

        ports = sim.ports()
        arms = {name: arm.model_copy(update={"port": ports[name]}) for name, arm in connector_config.arms.items()}
        connector = Connector(connector_config.model_copy(update={"arms": arms}), socket_dir,
                              camera_factory=simulated_camera_factory(source=sim), observer_dir=config.observer_dir,
                              record_dir=config.record_dir)
    else:
        connector = Connector(connector_config, socket_dir, observer_dir=config.observer_dir,
                              record_dir=config.record_dir)
    if restarted:
        connector.interlock.trip(TripReason.AGENT_RESTARTED, RESTARTED_MESSAGE)
    connector.start()
    print(f"armnet connector sidecar: serving {socket_dir}" + (" (restarted: interlock tripped)" if restarted else ""),
          file=sys.stderr, flush=True)
    try:
        while not stop.wait(SIGNAL_POLL_S):
            pass
    finally:
        record = connector_record(connector)
        connector.stop()
        record["safety"] = connector.safety_report().as_status()
        record["cell_record"] = connector.cell_record_counts()
        record["restarted"] = restarted
        print(record_line(record), flush=True)
        if sim is not None:
            sim.stop()
    exit_after_clean_stop(0)  # the record is out and torque off: skip the interpreter's slow teardown


def _start_simulator(simulator: Mapping[str, Any], connector_config: Any) -> Any:
    """The cell's simulator on this container's own ptys, seeded with the calibration the connector reads."""
    from armnet_sim.calibration import load_calibration
    from armnet_sim.process import SimulatedCellProcess

    calibrations = {name: load_calibration(arm.calibration_file) for name, arm in connector_config.arms.items()
                    if arm.calibration_file is not None}
    return SimulatedCellProcess(str(simulator["preset"]), calibrations=calibrations,
                                latency_ms=float(simulator.get("latency_ms", 0.0))).start()


def connector_record(connector: Any) -> dict[str, Any]:
    """The connector's account before its own stop trips the interlock (``shutdown`` is teardown, not news)."""
    trip = connector.interlock.trip_info
    rollout = None
    for event in reversed(list(connector.cell.rollouts)):
        if event.kind == "begin" and event.index is not None:
            rollout = event
            break
    events = list(connector.cell.rollouts)[-RECORD_ROLLOUT_EVENTS:]
    return {
        # Every field of an event (the observer socket's ``rollouts`` op gives the same): a verdict the
        # monitor records at the last rollout's end is read from here once the job has exited.
        "rollouts": [{"kind": e.kind, "at": e.at, "index": e.index, "total": e.total,
                      "outcome_controls": e.outcome_controls, "success": e.success, "score": e.score,
                      "frame_at": e.frame_at} for e in events],
        "trip_reason": trip.reason.value if trip is not None else None,
        "trip_message": trip.message if trip is not None else None,
        "safety_violations": connector.counters.safety_violations,
        "rollout_index": rollout.index if rollout is not None else None,
        "rollout_total": (rollout.total or 0) if rollout is not None else None,
    }


if __name__ == "__main__":
    raise SystemExit(main())
