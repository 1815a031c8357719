"""The chart's bundled object store (artifacts.deploy) run for real: its init script and its `weed mini`.

The test bed cannot pull the store's image, and pods on its node cannot reach a Service (no
kube-proxy), so the pod's steps run here as the pod would run them: the init container's
script in ``sh`` with the environment the rendered pod gets from its Secrets (:data:`KEYS`),
then its two containers' ``weed`` arguments with the SeaweedFS the test bed built: the
store (master, volume server, filer; on loopback as rendered) and its S3 gateway. What
changes is only where they run: the data directory, the identities file's path, the
gateway on loopback instead of every address, free ports instead of SeaweedFS's defaults.
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
#: The rendered flags a local run changes, per container (where it listens and keeps its files); the rest
#: run as rendered.
STORE_FLAGS = ("dir", "master.port", "master.port.grpc", "volume.port", "volume.port.grpc", "filer.port",
               "filer.port.grpc", "admin.port", "admin.port.grpc")
S3_FLAGS = ("ip.bind", "port", "port.grpc", "filer", "config")
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
    """The rendered pod's two ``weed`` processes on loopback; ``endpoint`` is its S3 gateway's URL."""

    workdir: Path
    objects: list[dict[str, Any]]
    ports: dict[str, int] = field(default_factory=lambda: {
        name: free_port() for name in (*STORE_FLAGS[1:], "s3", "s3.grpc")})
    _procs: list[ManagedProcess] = field(default_factory=list)

    @property
    def endpoint(self) -> str:
        return f"http://127.0.0.1:{self.ports['s3']}"

    def container(self, name: str) -> dict[str, Any]:
        found: dict[str, Any] = next(c for c in store_pod(self.objects)["containers"] if c["name"] == name)
        assert found["command"] == ["weed"], found["command"]
        return found

    def argv(self, container: str, local: dict[str, str]) -> list[str]:
        args = [arg for arg in self.container(container)["args"] if arg.lstrip("-").split("=", 1)[0] not in local]
        return [str(require_tool("weed", weed_binary())), *args, *(f"-{k}={v}" for k, v in local.items())]

    def start(self) -> ChartStore:
        result = run_config_script(self.objects, KEYS, self.workdir / "s3.json")
        assert result.returncode == 0, result.stderr
        (self.workdir / "data").mkdir(exist_ok=True)
        store = {"dir": str(self.workdir / "data"), **{k: str(self.ports[k]) for k in STORE_FLAGS[1:]}}
        s3 = {"ip.bind": "127.0.0.1", "port": str(self.ports["s3"]), "port.grpc": str(self.ports["s3.grpc"]),
              "filer": f"127.0.0.1:{self.ports['filer.port']}.{self.ports['filer.port.grpc']}",
              "config": str(self.workdir / "s3.json")}
        env = {**os.environ, "TMPDIR": str(self.workdir)}
        self._procs = [ManagedProcess("chart-store", self.argv("store", store), self.workdir / "store.log",
                                      env=env, cwd=self.workdir),
                       ManagedProcess("chart-store-s3", self.argv("s3", s3), self.workdir / "s3.log",
                                      env=env, cwd=self.workdir)]
        wait_until(self._ready, timeout=START_TIMEOUT_S, what=f"the chart's store on {self.endpoint}",
                   interval=0.5, alive=self._alive)
        return self

    def _alive(self) -> None:
        for proc in self._procs:
            proc.ensure_running()

    def _ready(self) -> bool:
        # Ready once the agent's keys find the bucket: `weed mini` makes it once its filer runs.
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
        for proc in reversed(self._procs):
            proc.stop()
        self._procs = []
