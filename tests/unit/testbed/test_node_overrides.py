"""The test-bed node's experiment overrides: another containerd, kubelet feature gates; off by default."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from armnet_testbed.containerd import (
    CONTAINERD_ROOT,
    PAUSE_IMAGE,
    containerd_config,
    containerd_major,
    containerd_root,
)
from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.node import feature_gates, kubelet_config

pytestmark = pytest.mark.unit

W = Path("/tmp/armnet-node-x")


def test_major_version_from_debian_and_upstream_output() -> None:
    assert containerd_major("containerd github.com/containerd/containerd 1.6.20~ds1 1.6.20~ds1-1+deb12u3\n") == 1
    assert containerd_major("containerd github.com/containerd/containerd/v2 2.2.1+unknown \n") == 2
    assert containerd_major("containerd github.com/containerd/containerd/v2 v2.2.1 abcdef\n") == 2
    with pytest.raises(TestbedSetupError):
        containerd_major("")


def test_default_config_is_schema_2_unchanged() -> None:
    config = tomllib.loads(containerd_config(W, Path("/root"), W / "cni"))
    assert config["version"] == 2
    cri = config["plugins"]["io.containerd.grpc.v1.cri"]
    assert cri["sandbox_image"] == PAUSE_IMAGE and cri["restrict_oom_score_adj"] is True
    assert "runtime_path" not in cri["containerd"]["runtimes"]["runc"]


def test_containerd_2_gets_schema_3_with_the_same_settings() -> None:
    shim = Path("/opt/c2/containerd-shim-runc-v2")
    config = tomllib.loads(containerd_config(W, Path("/root-v2"), W / "cni", major=2, shim=shim))
    assert config["version"] == 3 and config["root"] == "/root-v2"
    assert config["grpc"]["address"] == str(W / "containerd.sock")
    assert "io.containerd.nri.v1.nri" in config["disabled_plugins"]
    images = config["plugins"]["io.containerd.cri.v1.images"]
    assert images["pinned_images"]["sandbox"] == PAUSE_IMAGE and images["snapshotter"] == "overlayfs"
    runtime = config["plugins"]["io.containerd.cri.v1.runtime"]
    assert runtime["restrict_oom_score_adj"] is True and runtime["enable_cdi"] is False
    assert runtime["cni"] == {"bin_dirs": ["/usr/lib/cni"], "conf_dir": str(W / "cni"), "max_conf_num": 1}
    runc = runtime["containerd"]["runtimes"]["runc"]
    assert runc["runtime_path"] == str(shim)
    assert runc["options"] == {"SystemdCgroup": False, "Root": str(W / "state" / "runc")}
    assert config["plugins"]["io.containerd.grpc.v1.cri"]["stream_server_port"] == "0"


def test_containerd_2_override_gets_a_root_of_its_own_unless_one_is_set() -> None:
    assert containerd_root(1, overridden=False, env={}) == CONTAINERD_ROOT
    assert containerd_root(1, overridden=True, env={}) == CONTAINERD_ROOT
    assert containerd_root(2, overridden=True, env={}) == CONTAINERD_ROOT.with_name(CONTAINERD_ROOT.name + "-v2")
    assert containerd_root(2, overridden=True, env={"ARMNET_NODE_CONTAINERD_ROOT": "/x"}) == CONTAINERD_ROOT


def test_kubelet_feature_gates_only_when_asked() -> None:
    def config(gates: dict[str, bool] | None = None) -> dict[str, Any]:
        return kubelet_config(socket=W / "sock", node_ip="198.18.0.10", port=1, healthz_port=2, ca_cert=W / "ca",
                              tls_cert=W / "crt", tls_key=W / "key", pod_logs=W / "logs", gates=gates)

    plain = config()
    assert "featureGates" not in plain
    assert feature_gates("") == {}
    gated = config(feature_gates("EventedPLEG=true, Foo=False"))
    assert gated == {**plain, "featureGates": {"EventedPLEG": True, "Foo": False}}
    with pytest.raises(TestbedSetupError):
        feature_gates("EventedPLEG")
