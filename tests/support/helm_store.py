"""The chart's bundled object store (artifacts.deploy) run for real: its init script and its `weed mini`.

The test bed cannot pull the store's image, and pods on its node cannot reach a Service (no
kube-proxy), so the pod's two steps run here as the pod would run them: the init
container's script in ``sh`` with the environment the rendered pod gets from its Secrets
(:data:`KEYS`), then the rendered container's ``weed`` arguments with the SeaweedFS the test
bed built. What changes is only where it runs: its data directory, the identities file's
path, loopback instead of every address, free ports instead of SeaweedFS's defaults.
"""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from armnet_core.object_store import StoreConfig
from armnet_testbed.objstore import weed_binary
from armnet_testbed.procs import ManagedProcess, free_port, require_tool, wait_until

from tests.support.helm import find, render

BUCKET = "armnet-outputs"
#: Every Secret the test values name, as the cluster would hold them (keys accessKeyId, secretAccessKey).
KEYS = {
    "agent-keys": {"accessKeyId": "agentAKIA0001", "secretAccessKey": "agent/secret+0001="},
    "operator-keys": {"accessKeyId": "operatorAKIA0002", "secretAccessKey": "operator-secret-0002"},
    "fms-keys": {"accessKeyId": "fmsAKIA0003", "secretAccessKey": "fms.secret_0003"},
    "team-a-outputs": {"accessKeyId": "teamaAKIA0004", "secretAccessKey": "team~a~secret~0004"},
    "team-b-outputs": {"accessKeyId": "teambAKIA0005", "secretAccessKey": "team-b-secret-0005"},
}
VALUES: dict[str, Any] = {"artifacts": {
    "bucket": BUCKET, "credentialsSecret": "agent-keys", "operatorCredentialsSecret": "operator-keys",
    "fmsCredentialsSecret": "fms-keys",
    "deploy": {"enabled": True, "tenantReaders": [
        {"namespace": "team-a", "credentialsSecret": "team-a-outputs"},
        {"namespace": "team-b", "credentialsSecret": "team-b-outputs"}]},
}, "fms": {"enabled": True, "existingSecret": "fms-login"}}
#: The rendered flags a local run changes (where it listens and keeps its files); the rest run as rendered.
LOCAL_FLAGS = ("dir", "ip.bind", "s3.config", "s3.port", "s3.port.grpc", "master.port", "master.port.grpc",
               "volume.port", "volume.port.grpc", "filer.port", "filer.port.grpc", "admin.port", "admin.port.grpc")
START_TIMEOUT_S = 120


def rendered(values: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    return render(values=values or VALUES)


def store_pod(objects: list[dict[str, Any]]) -> dict[str, Any]:
    spec: dict[str, Any] = find(objects, "StatefulSet", "-store")["spec"]["template"]["spec"]
    return spec


def pod_env(container: dict[str, Any], secrets: dict[str, dict[str, str]], **overrides: str) -> dict[str, str]:
    """The environment the kubelet gives ``container``: values as rendered, Secret references resolved
    (references to the pod's own fields, its node name say, are left out: none is about the store)."""
    env: dict[str, str] = {}
    for entry in container.get("env", []):
        if "value" in entry:
            env[entry["name"]] = entry["value"]
        elif "secretKeyRef" in entry.get("valueFrom", {}):
            ref = entry["valueFrom"]["secretKeyRef"]
            env[entry["name"]] = secrets[ref["name"]][ref["key"]]
    return {**env, **overrides}


def run_config_script(objects: list[dict[str, Any]], secrets: dict[str, dict[str, str]],
                      config: Path) -> subprocess.CompletedProcess[str]:
    """The init container's command, as the pod runs it, writing the identities file to ``config``."""
    init = store_pod(objects)["initContainers"][0]
    env = {"PATH": os.environ["PATH"], **pod_env(init, secrets, S3_CONFIG=str(config))}
    return subprocess.run(init["command"], env=env, capture_output=True, text=True, timeout=30, check=False)


def store_config(objects: list[dict[str, Any]], kind: str, name_suffix: str, container: str,
                 endpoint: str) -> StoreConfig:
    """What a component's rendered env tells it about the store (``StoreConfig.from_env``), reached at ``endpoint``."""
    spec = find(objects, kind, name_suffix)["spec"]["template"]["spec"]
    env = pod_env(next(c for c in spec["containers"] if c["name"] == container), KEYS)
    config = StoreConfig.from_env({**env, "ARMNET_ARTIFACTS_ENDPOINT": endpoint})
    assert config is not None, f"{kind} *{name_suffix} gets no store from the chart"
    return config


@dataclass
class ChartStore:
    """The rendered store container's ``weed`` on loopback; ``endpoint`` is its S3 URL."""

    workdir: Path
    objects: list[dict[str, Any]]
    ports: dict[str, int] = field(default_factory=lambda: {
        flag: free_port() for flag in LOCAL_FLAGS if flag.endswith("port") or flag.endswith(".grpc")})
    _proc: ManagedProcess | None = None

    @property
    def endpoint(self) -> str:
        return f"http://127.0.0.1:{self.ports['s3.port']}"

    def argv(self) -> list[str]:
        container = store_pod(self.objects)["containers"][0]
        assert container["command"] == ["weed"], container["command"]
        local = {"dir": str(self.workdir / "data"), "ip.bind": "127.0.0.1",
                 "s3.config": str(self.workdir / "s3.json"), **{k: str(v) for k, v in self.ports.items()}}
        args = [arg for arg in container["args"] if arg.lstrip("-").split("=", 1)[0] not in local]
        return [str(require_tool("weed", weed_binary())), *args, *(f"-{k}={v}" for k, v in local.items())]

    def start(self) -> ChartStore:
        result = run_config_script(self.objects, KEYS, self.workdir / "s3.json")
        assert result.returncode == 0, result.stderr
        (self.workdir / "data").mkdir(exist_ok=True)
        self._proc = ManagedProcess("chart-store", self.argv(), self.workdir / "weed.log", cwd=self.workdir)
        wait_until(self._ready, timeout=START_TIMEOUT_S, what=f"the chart's store on {self.endpoint}",
                   interval=0.5, alive=self._proc.ensure_running)
        return self

    def _ready(self) -> bool:
        # Ready once the agent's keys find the bucket: `weed mini` makes it after its S3 gateway answers.
        from armnet_core.object_store import s3_client
        from botocore.exceptions import BotoCoreError, ClientError

        agent = StoreConfig(BUCKET, KEYS["agent-keys"]["accessKeyId"], KEYS["agent-keys"]["secretAccessKey"],
                            self.endpoint)
        try:
            s3_client(agent, max_attempts=1, connect_timeout=2, read_timeout=5).head_bucket(Bucket=BUCKET)
        except (BotoCoreError, ClientError):
            return False
        return True

    def stop(self) -> None:
        if self._proc is not None:
            self._proc.stop()
            self._proc = None
