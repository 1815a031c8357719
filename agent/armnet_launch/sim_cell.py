"""The in-process simulated cell of one job: simulator, cameras, connector.

Local runs and the node agent's simulated cells both use it. This module owns
starting and stopping them together on a run directory laid out by
``cell_spec.plan_layout`` (the agent passes its own layout, with the cell's
cache and the namespace's volume elsewhere, and a simulator it keeps running
between jobs): it writes the calibration files (the same
ones that seed the simulated servos, so LeRobot's ``connect()`` finds them
calibrated), starts the simulator (one simulated bus per arm, in a child process:
``sim/process.py`` says why), and serves the real connector on
``<run_dir>/sockets``. The job deadline clock stays with the supervisor; the
connector is only told when the deadline passes (``pass_deadline``).
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from armnet_connector import ArmConfig, CameraConfig, Connector, ConnectorConfig
from armnet_connector.hardware import simulated_camera_factory
from armnet_connector.inputs import (
    InputFeeder,
    LocalOperatorInputs,
    OperatorInputs,
    terminal_prompt,
)
from armnet_connector.interlock import TripReason
from armnet_sim.calibration import builtin_calibration, load_calibration, write_calibration
from armnet_sim.presets import PRESETS, CellSimulator
from armnet_sim.process import SimulatedCellProcess

from armnet_launch.cell_spec import CellLayout, LocalCellSpec, plan_layout

log = logging.getLogger(__name__)


def build_connector_config(spec: LocalCellSpec, layout: CellLayout, ports: dict[str, str]) -> ConnectorConfig:
    """The connector's view of the local cell: each arm's pty, calibration and limit, the cameras.

    No ``timeout_seconds``: the supervisor owns the job clock and calls
    ``Connector.pass_deadline`` at the deadline, so there is one clock only.
    """
    return ConnectorConfig(
        arms={
            arm.name: ArmConfig(
                port=ports[arm.name],
                calibration_file=arm.calibration_file,
                robot_id=arm.robot_id,
                safety_limit=spec.safety_limit,
            )
            for arm in layout.arms
        },
        cameras={
            camera.name: CameraConfig(
                index_or_path=camera.name, fps=camera.fps, width=camera.width, height=camera.height
            )
            for camera in spec.cameras
        },
        simulated=True,
        timeout_seconds=None,
        grace_period_seconds=spec.grace_seconds,
        reset_timeout_seconds=spec.reset_timeout_seconds,
        safety_policy="trip" if spec.safety_policy == "trip" else "clamp",
        allow_calibration_jobs=spec.allow_calibration_jobs,
        register_bounds=dict(spec.register_bounds),
        completion=spec.completion,
        reset=spec.reset,
    )


class LocalCell:
    """Context manager: a started simulated cell with its connector, torn down on exit."""

    def __init__(
        self,
        spec: LocalCellSpec,
        run_dir: Path,
        *,
        auto_confirm_reset: bool = False,
        inputs_source: str | None = None,
        on_grace_expired: Callable[[], None] | None = None,
        layout: CellLayout | None = None,
        sim: CellSimulator | None = None,
        inputs: OperatorInputs | None = None,
        tripped: str | None = None,
        timeout_s: float | None = None,
    ) -> None:
        """``sim``: a running simulator owned by the caller (kept on exit), else one is started.

        ``tripped``: start with the interlock already tripped, with this reason
        (a connector re-created for a job it did not see start never resumes motion).
        ``timeout_s``: the job's timeout, which ``pass_deadline`` names (the supervisor's clock runs it).
        """
        self.spec = spec
        self.timeout_s = timeout_s
        self.layout = layout or plan_layout(spec, run_dir)
        prompt = terminal_prompt if sys.stdin.isatty() and not auto_confirm_reset else None
        self.inputs: OperatorInputs = inputs or LocalOperatorInputs(
            auto_confirm_reset=auto_confirm_reset, on_reset_requested=prompt
        )
        self._inputs_source = inputs_source
        self._on_grace_expired = on_grace_expired
        self._owns_sim = sim is None
        self.sim: CellSimulator | None = sim
        self._tripped = tripped
        self.connector: Connector | None = None

    def __enter__(self) -> LocalCell:
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def _start(self) -> None:
        layout = self.layout
        for directory in (layout.socket_dir, layout.calibration_dir, layout.cache_dir, layout.volume_dir,
                          layout.output_dir):
            directory.mkdir(parents=True, exist_ok=True)
        calibrations = {}
        shipped = {preset.name: preset.calibration for preset in PRESETS[self.spec.preset]}
        for arm in layout.arms:
            override = self.spec.calibration_files.get(arm.name)
            calibration = load_calibration(override) if override else builtin_calibration(shipped[arm.name])
            write_calibration(arm.calibration_file, calibration)
            calibrations[arm.name] = calibration
        if self.sim is None:
            self.sim = SimulatedCellProcess(self.spec.preset, calibrations=calibrations,
                                            latency_ms=self.spec.latency_ms).start()
        config = build_connector_config(self.spec, layout, self.sim.ports())
        self.connector = Connector(
            config,
            layout.socket_dir,
            inputs=self.inputs,
            camera_factory=simulated_camera_factory(source=self.sim),
            on_grace_expired=self._on_grace_expired,
            record_dir=layout.record_dir,
        ).start()
        if self._tripped is not None:
            self.connector.interlock.trip(TripReason.AGENT_RESTARTED, self._tripped)
        if self._inputs_source is not None and isinstance(self.inputs, LocalOperatorInputs):
            InputFeeder(self.inputs, self._inputs_source).start()

    def pass_deadline(self) -> None:
        """The job hit its timeout: trip the interlock and open the grace window."""
        if self.connector is not None:
            self.connector.pass_deadline(self.timeout_s)

    def cancel(self, why: str | None = None) -> None:
        """The job was cancelled (or stopped for ``why``): trip the interlock, naming it, and open the grace window."""
        if self.connector is not None:
            self.connector.cancel(why)

    def stop_connector(self) -> None:
        """Stop the connector: it lets go of every arm (torque off, read back) and stays readable.

        Why apart from ``stop``: the job's record must hold the connector's final
        release, which exists only once it has stopped; the caller reads the record
        after this, then ``stop`` (or the ``with`` exit) tears the rest down.
        """
        if self.connector is not None:
            # Stopping trips the interlock by design; that is teardown, not news for the user.
            connector_log = logging.getLogger("armnet_connector")
            level = connector_log.level
            connector_log.setLevel(logging.ERROR)
            try:
                self.connector.stop()
            finally:
                connector_log.setLevel(level)

    def stop(self) -> None:
        self.stop_connector()
        self.connector = None
        if self.sim is not None and self._owns_sim:
            self.sim.stop()
        self.sim = None
