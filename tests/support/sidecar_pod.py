"""A real connector as a pod's sidecar runs it, on the simulated SO-101 (the path of ``--launcher pod``).

The job's sockets are in one directory (the volume the tenant's container mounts); the
agent's (``observer.sock`` and ``agent.sock``) in another, a volume of the sidecar only,
reached as the agent reaches it on the host: through the kubelet's long volume path,
longer than a unix socket address holds.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

from armnet_connector import Connector, LocalOperatorInputs
from armnet_connector.agent_inputs import AGENT_SOCKET
from armnet_connector.observer import OBSERVER_SOCKET
from armnet_runtime.context import Cell
from armnet_sim import SimulatedCellProcess

from tests.support.sim_connector import cell_config, request

#: The kubelet's directory of the pod's volumes, as long as on a real node.
_POD_VOLUMES = Path("kubelet") / "pods" / "0f2b7c1e-8d4a-4f3e-9b6a-1c2d3e4f5a6b" / "volumes"
#: A unix socket's address holds at most this many bytes.
_SUN_PATH_MAX = 108


class Pod:
    """A connector as the sidecar runs it: the job's sockets in one directory, the agent's in another.

    ``config`` overrides the cell's connector configuration (``grace_period_seconds=...``).
    """

    def __init__(self, sim: SimulatedCellProcess, **config: Any) -> None:
        self.top = Path(tempfile.mkdtemp(prefix="ant-pod-", dir="/tmp"))
        self.sockets = self.top / "sockets"
        self.agent_dir = self.top / "observer"
        self.config = cell_config(sim).model_copy(update=config)
        self.inputs, self.connector = self._start()
        volume = self.top / _POD_VOLUMES / "kubernetes.io~empty-dir"
        volume.mkdir(parents=True)
        (volume / "observer").symlink_to(self.agent_dir)
        #: The agent's sockets as the agent finds them on the host.
        self.observer_path = volume / "observer" / OBSERVER_SOCKET
        self.agent_path = volume / "observer" / AGENT_SOCKET
        assert min(len(str(p).encode()) for p in (self.observer_path, self.agent_path)) > _SUN_PATH_MAX

    def _start(self) -> tuple[LocalOperatorInputs, Connector]:
        inputs = LocalOperatorInputs()
        return inputs, Connector(self.config, self.sockets, inputs=inputs, observer_dir=self.agent_dir).start()

    def restart(self) -> None:
        """The kubelet restarts the sidecar: a new connector serves the same volumes."""
        self.connector.stop()
        self.inputs, self.connector = self._start()

    def job_cell(self) -> Cell:
        """The customer SDK's cell handle, as the job's context builds it in the pod."""
        return Cell(operator_call_endpoint=self.connector.operator_endpoint)

    def operator_op(self, op: str, **fields: Any) -> dict[str, Any]:
        """What the job's SDK sends on its operator socket (``ctx.cell.rollout_begin`` ...)."""
        return request(self.sockets / "operator.sock", {"op": op, **fields})

    def close(self) -> None:
        self.connector.stop()
        shutil.rmtree(self.top, ignore_errors=True)
