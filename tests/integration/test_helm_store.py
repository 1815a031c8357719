"""The chart deploys the object store of job outputs (artifacts.deploy): each key reaches what it should.

The rendered pod runs for real (tests/support/helm_store.py): its init script writes the
identities from the Secrets, its `weed mini` creates the bucket; then the product's own
clients use the keys the chart gives each component: the agent's upload
(``armnet_node.artifacts.upload_output``), the operator's removal at a job's TTL
(``OutputsStore``), the FMS's reads, a tenant's reads of its namespace's outputs.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.object_store import StoreConfig, s3_client
from armnet_node.artifacts import ObjectStore
from armnet_node.artifacts.keys import manifest_key, object_key
from armnet_node.artifacts.upload import upload_output
from armnet_operator.outputs_store import OutputsStore
from botocore.exceptions import ClientError

from tests.support.helm import CHART, find, helm
from tests.support.helm_store import (
    BUCKET,
    KEYS,
    VALUES,
    ChartStore,
    rendered,
    run_config_script,
    store_config,
    store_pod,
)

pytestmark = pytest.mark.integration

FILES = {"data/episode_000000.parquet": b"\x01" * 3000, "meta/info.json": b'{"fps": 30}'}


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ChartStore]:
    chart_store = ChartStore(tmp_path_factory.mktemp("helm-store"), rendered()).start()
    yield chart_store
    chart_store.stop()


def keys_of(store: ChartStore, secret: str) -> Any:
    """A plain S3 client with the keys of one of the Secrets."""
    return s3_client(StoreConfig(BUCKET, KEYS[secret]["accessKeyId"], KEYS[secret]["secretAccessKey"],
                                 store.endpoint), max_attempts=1)


def stored_by_the_agent(store: ChartStore, tmp_path: Path, namespace: str) -> str:
    """A job's outputs uploaded by the agent's own code with the agent's keys from the chart; the prefix."""
    root = tmp_path / f"output-{namespace}"
    for path, data in FILES.items():
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        (root / path).write_bytes(data)
    uid = str(uuid.uuid4())
    agent = ObjectStore(store_config(store.objects, "DaemonSet", "-agent", "agent", store.endpoint))
    report = upload_output(root, agent, namespace, uid)
    assert sorted(a.path for a in report.artifacts) == sorted(FILES), report
    return f"{namespace}/{uid}/"


def denied(call: Any, *args: Any, **kwargs: Any) -> bool:
    try:
        call(*args, **kwargs)
    except ClientError as error:
        return error.response["Error"]["Code"] in ("AccessDenied", "403")
    return False


def test_the_store_makes_the_bucket_and_stores_the_agents_uploads(store: ChartStore, tmp_path: Path) -> None:
    prefix = stored_by_the_agent(store, tmp_path, "team-a")
    agent = keys_of(store, "agent-keys")

    listed = {o["Key"]: o["Size"] for o in agent.list_objects_v2(Bucket=BUCKET, Prefix=prefix)["Contents"]}
    assert {object_key(prefix, path): len(data) for path, data in FILES.items()}.items() <= listed.items()
    assert manifest_key(prefix) in listed
    assert denied(agent.create_bucket, Bucket="another-bucket")


def test_the_operators_keys_remove_a_jobs_outputs_at_its_ttl(store: ChartStore, tmp_path: Path) -> None:
    prefix = stored_by_the_agent(store, tmp_path, "team-b")
    operator = OutputsStore(store_config(store.objects, "Deployment", "-operator", "operator", store.endpoint))

    removed = operator.remove(prefix)

    assert removed >= len(FILES)
    assert keys_of(store, "agent-keys").list_objects_v2(Bucket=BUCKET, Prefix=prefix).get("KeyCount") == 0


def test_the_fms_keys_read_and_never_write_or_delete(store: ChartStore, tmp_path: Path) -> None:
    prefix = stored_by_the_agent(store, tmp_path, "team-a")
    fms = s3_client(store_config(store.objects, "Deployment", "-fms", "fms", store.endpoint), max_attempts=1)
    key = object_key(prefix, "meta/info.json")

    assert fms.get_object(Bucket=BUCKET, Key=key)["Body"].read() == FILES["meta/info.json"]
    assert denied(fms.put_object, Bucket=BUCKET, Key=prefix + "forged.json", Body=b"{}")
    assert denied(fms.delete_object, Bucket=BUCKET, Key=key)
    assert keys_of(store, "agent-keys").get_object(Bucket=BUCKET, Key=key)["Body"].read() == FILES["meta/info.json"]


def test_a_tenants_keys_read_only_its_own_namespaces_outputs(store: ChartStore, tmp_path: Path) -> None:
    own, other = stored_by_the_agent(store, tmp_path, "team-a"), stored_by_the_agent(store, tmp_path, "team-b")
    own_key, other_key = object_key(own, "meta/info.json"), object_key(other, "meta/info.json")
    tenant = keys_of(store, "team-a-outputs")

    assert tenant.get_object(Bucket=BUCKET, Key=own_key)["Body"].read() == FILES["meta/info.json"]
    assert denied(tenant.get_object, Bucket=BUCKET, Key=other_key)
    assert denied(tenant.put_object, Bucket=BUCKET, Key=own + "forged.json", Body=b"{}")
    assert denied(tenant.delete_object, Bucket=BUCKET, Key=own_key)


def test_a_restarted_store_keeps_its_bucket_and_outputs(tmp_path: Path) -> None:
    chart_store = ChartStore(tmp_path, rendered()).start()
    try:
        prefix = stored_by_the_agent(chart_store, tmp_path, "team-a")
        chart_store.stop()
        chart_store.start()  # the same data: the bucket is there already, the outputs too
        listed = keys_of(chart_store, "agent-keys").list_objects_v2(Bucket=BUCKET, Prefix=prefix)
        assert listed.get("KeyCount", 0) >= len(FILES), listed
    finally:
        chart_store.stop()


@pytest.mark.parametrize("secret, key, value", [
    ("fms-keys", "secretAccessKey", 'x", "actions": ["Admin"], "y": "'),
    ("team-a-outputs", "accessKeyId", "has space"),
    ("agent-keys", "accessKeyId", ""),
])
def test_the_init_script_refuses_a_key_the_identities_file_cannot_hold(
        tmp_path: Path, secret: str, key: str, value: str) -> None:
    config = tmp_path / "s3.json"
    hostile = {**KEYS, secret: {**KEYS[secret], key: value}}

    result = run_config_script(rendered(), hostile, config)

    assert result.returncode == 1
    assert f"key {key} of Secret {secret}" in result.stderr, result.stderr
    assert not config.exists() and not config.with_suffix(".json.partial").exists()


def test_the_init_script_refuses_two_identities_with_one_access_key(tmp_path: Path) -> None:
    config = tmp_path / "s3.json"
    shared = {**KEYS, "team-b-outputs": {**KEYS["team-b-outputs"], "accessKeyId": KEYS["agent-keys"]["accessKeyId"]}}

    result = run_config_script(rendered(), shared, config)

    assert result.returncode == 1 and "hold the same accessKeyId" in result.stderr, result.stderr
    assert not config.exists()


def test_the_agent_operator_and_fms_are_pointed_at_the_store_service() -> None:
    objects = rendered()
    service = find(objects, "Service", "-store")

    url = f"http://{service['metadata']['name']}.armnet-system.svc:8333"
    for kind, suffix, container in (("DaemonSet", "-agent", "agent"), ("Deployment", "-operator", "operator"),
                                    ("Deployment", "-fms", "fms")):
        assert store_config(objects, kind, suffix, container, url).endpoint_url == url
    assert [p["port"] for p in service["spec"]["ports"]] == [8333]


def test_only_the_s3_gateway_listens_beyond_the_pods_loopback() -> None:
    """The master, volume and filer ports take no credentials: they listen on loopback whatever the network
    enforces; the NetworkPolicy fences the gateway's port too."""
    pod = store_pod(rendered())
    store, s3 = (next(c for c in pod["containers"] if c["name"] == name) for name in ("store", "s3"))
    policy = find(rendered(), "NetworkPolicy", "-store")

    assert {"-ip=127.0.0.1", "-ip.bind=127.0.0.1", "-s3=false", "-webdav=false", "-admin.ui=false"} <= set(store["args"])
    assert "ports" not in store
    assert "-ip.bind=0.0.0.0" in s3["args"] and [p["containerPort"] for p in s3["ports"]] == [8333]
    assert policy["spec"]["policyTypes"] == ["Ingress"]
    assert [[p["port"] for p in rule["ports"]] for rule in policy["spec"]["ingress"]] == [[8333]]


def _refusal(values: dict[str, Any]) -> str:
    result = helm("template", "armnet", str(CHART), "--values", "-", input=yaml.safe_dump(values), check=False)
    assert result.returncode != 0, "the chart rendered values it should refuse"
    return result.stderr


@pytest.mark.parametrize("change, says", [
    ({"bucket": ""}, "artifacts.deploy.enabled needs artifacts.bucket"),
    ({"credentialsSecret": ""}, "but artifacts.credentialsSecret is not"),
    ({"endpoint": "http://s3.example.com"}, "artifacts.endpoint and artifacts.deploy.enabled are both set"),
    ({"fmsCredentialsSecret": "agent-keys"}, "share the Secret agent-keys"),
    ({"bucket": "Outputs_1"}, "bucket"),
])
def test_the_chart_refuses_a_store_it_cannot_deploy(change: dict[str, Any], says: str) -> None:
    values = {**VALUES, "artifacts": {**VALUES["artifacts"], **change}}

    assert says in _refusal(values)


def test_the_chart_refuses_a_tenant_namespace_named_twice() -> None:
    readers = [{"namespace": "team-a", "credentialsSecret": "a1"}, {"namespace": "team-a", "credentialsSecret": "a2"}]
    deploy = {**VALUES["artifacts"]["deploy"], "tenantReaders": readers}

    assert "names namespace team-a twice" in _refusal({**VALUES, "artifacts": {**VALUES["artifacts"], "deploy": deploy}})
