"""``ArmnetRelayConfig``: the LeRobot teleoperator config of armnet's teleop relay.

Registered with LeRobot as ``armnet_relay``, so LeRobot's own recording code
(``lerobot_record.record(RecordConfig(teleop=...))``) drives the cell from the
leader arm of whoever teleoperates it through armnet (``armnet teleop``, the cell
operator's page), with no change to that code.

Kept apart from the device (``relay``) because LeRobot finds a device from its
config's module: ``make_device_from_device_class`` strips ``Config`` from the
class name and looks in this module's package, which exports ``ArmnetRelay``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional

from lerobot.teleoperators.config import TeleoperatorConfig

if TYPE_CHECKING:
    from armnet_runtime.context import Cell

#: LeRobot's name for this teleoperator (``--teleop.type=armnet_relay``).
RELAY_TYPE = "armnet_relay"


@TeleoperatorConfig.register_subclass(RELAY_TYPE)
@dataclass(kw_only=True)
class ArmnetRelayConfig(TeleoperatorConfig):  # type: ignore[misc]  # LeRobot ships no type information
    """Where the relay reads the operator's actions, and what it sends before the first one.

    ``hold`` names every action key the robot takes (``"shoulder_pan.pos"``, ...) with
    the value sent until the operator's leader arm moves that joint: the follower's
    pose when the recording starts, so an unattended recording holds still.
    """

    hold: dict[str, float] = field(default_factory=dict)
    operator_call_endpoint: Optional[str] = None
    local_control_endpoint: Optional[str] = None

    @classmethod
    def for_cell(cls, cell: Cell, hold: dict[str, float]) -> ArmnetRelayConfig:
        """The relay of the job's own cell (``ctx.cell``), holding ``hold`` until the operator acts."""
        return cls(hold=dict(hold), operator_call_endpoint=cell.operator_call_endpoint,
                   local_control_endpoint=cell.local_control_endpoint)
