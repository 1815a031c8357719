"""The manifest fuzzer: random and hostile RobotJob and Cell manifests against the real
API server, with the operator running.

After every few manifests a probe job of another embodiment must bind to a
healthy cell within ``PROBE_SECONDS``; the operator's loop must still run; every
rejection by the API server must name the field it rejects. Short by default
(``ARMNET_FUZZ_MANIFESTS`` examples, 12); ``bench/fuzz_manifests.sh`` runs it
longer.
"""

from __future__ import annotations

import itertools
import json
import os
import time
from typing import Any

import pytest
from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, VERSION
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from kubernetes.client import ApiException

from tests.integration.operator_bed import Bed, running_operator

pytestmark = [
    pytest.mark.integration,
    # The API clients in the operator's threads use the random module while examples run; the
    # strategies do not (hypothesis cannot tell the two apart).
    pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisDeprecationWarning"),
]

EXAMPLES = int(os.environ.get("ARMNET_FUZZ_MANIFESTS", "12"))
PROBE_EVERY = 4
PROBE_SECONDS = 10.0  # "within seconds" on a loaded 2-core VM; a quiet one binds in well under 1 s
NAMES = itertools.count()

huge_ints = st.one_of(st.integers(-(2**63), 2**63 - 1), st.sampled_from([0, -1, 1, 2**31, 2**53 + 1, 10**18]))
odd_floats = st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([0.0, -1.0, 1e9, 45.0, 45.01]))
words = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=40)
paths = st.one_of(words, st.sampled_from(["../../etc/passwd", "/var/lib/../..", "/dev/ttyACM0", "/dev/ttyACM1",
                                           "relative/dir", "/", "/dev/tty\u0000x", "/var/lib/armnet/cal/x"]))
json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), huge_ints, odd_floats, words),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(words, children, max_size=4)),
    max_leaves=20,
)


def deep(levels: int) -> dict[str, Any]:
    value: dict[str, Any] = {"leaf": 1}
    for _ in range(levels - 1):
        value = {"a": value}
    return value


# Up to 600 levels: hypothesis lowers the process's recursion limit to ~2,000 frames while an
# example runs, and both the API client's serializer (two frames per level) and the in-process
# operator's watch decoder live in this process. A thousand levels and more, sent as text, are
# test_operator_hostile_live's and test_operator_webhook_live's cases.
hostile_args = st.one_of(
    st.dictionaries(words, json_values, max_size=6),
    st.integers(20, 600).map(deep),
    st.integers(1, 1100).map(lambda kib: {"blob": "x" * (kib * 1024)}),
    json_values,
)


@st.composite
def robotjobs(draw: st.DrawFn, embodiment: str) -> dict[str, Any]:
    # Mostly a valid image and embodiment, so most manifests get past the API server to the operator.
    spec: dict[str, Any] = {
        "image": draw(words) if draw(st.integers(0, 5)) == 0 else "localhost/armnet-test:dev",
        "embodiment": draw(words) if draw(st.integers(0, 5)) == 0 else embodiment,
    }
    optional = {
        "args": hostile_args, "priority": huge_ints, "timeoutSeconds": huge_ints,
        "ttlSecondsAfterFinished": huge_ints, "task": words, "cancel": st.booleans(),
        "detach": st.one_of(st.booleans(), words), "secrets": st.dictionaries(words, words, max_size=3),
        "unknownField": json_values,
    }
    for key, strategy in optional.items():
        if draw(st.booleans()):
            spec[key] = draw(strategy)
    return {"kind": "RobotJob", "spec": spec, "status": draw(st.one_of(st.none(), st.fixed_dictionaries({}, optional={
        "phase": st.sampled_from(["queued", "dispatched", "running", "succeeded", "failed", "exploded"]),
        "cellName": words, "finishedAt": st.sampled_from(["0000-01-01T00:00:00Z", "2026-01-01T00:00:00Z", "soon"]),
        "queuePosition": huge_ints}))), "status_target": draw(st.booleans())}


@st.composite
def cells(draw: st.DrawFn, embodiment: str) -> dict[str, Any]:
    arm = st.fixed_dictionaries({}, optional={
        "port": paths, "robotId": words, "calibrationDir": paths, "safetyLimit": odd_floats})
    spec: dict[str, Any] = {
        "embodiment": draw(st.one_of(st.just(embodiment), st.just("lerobot/bimanual_so101"), words)),
        "nodeName": draw(st.one_of(st.just("fuzz-host"), words)),
    }
    if draw(st.booleans()):
        spec["robot"] = draw(arm)
    if draw(st.booleans()):
        spec["arms"] = draw(st.dictionaries(st.sampled_from(["left", "right", "third", ""]), arm, max_size=3))
    for key in ("gracePeriodSeconds", "resetTimeoutSeconds"):
        if draw(st.booleans()):
            spec[key] = draw(huge_ints)
    if draw(st.booleans()):
        spec["cameras"] = {"c": draw(st.fixed_dictionaries({"indexOrPath": st.one_of(huge_ints, paths)},
                                                           optional={"fps": huge_ints, "width": huge_ints}))}
    if draw(st.booleans()):
        spec["task"] = draw(words)
    return {"kind": "Cell", "spec": spec}


def names_its_field(error: ApiException) -> bool:
    body = json.loads(error.body or "{}")
    causes = (body.get("details") or {}).get("causes") or []
    # A cause without a field is a CEL rule at an object's root (it names its field in the message).
    return bool(causes) and all(c.get("field") or "spec." in c.get("message", "") for c in causes)


def test_hostile_manifests_never_stop_the_operator_and_a_good_cell_keeps_binding(
    bed: Bed, k8s: Any, namespace: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    good = bed.cell("good")
    fuzz_embodiment = f"fuzz/{bed.ns}"
    created_cells: list[str] = []
    probes = itertools.count()
    latencies: list[float] = []

    def probe(controller: Any) -> None:
        name = f"probe-{next(probes)}"
        started = time.monotonic()
        bed.job(name)
        bed.wait_job(name, phase="dispatched", cellName=good)
        latencies.append(time.monotonic() - started)
        assert latencies[-1] < PROBE_SECONDS, f"probe bound after {latencies[-1]:.1f}s"
        bed.agent_sets(name, "succeeded")
        bed.wait("the good cell free again", lambda: not bed.get_cell(good).get("status", {}).get("currentJob"))
        assert not controller.dead

    with running_operator(k8s, namespace, monkeypatch) as controller:
        rejections: list[str] = []

        @settings(max_examples=EXAMPLES, deadline=None, derandomize=False, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(manifest=st.one_of(robotjobs(fuzz_embodiment), cells(fuzz_embodiment)))
        def one(manifest: dict[str, Any]) -> None:
            index = next(NAMES)
            name = f"fz-{index}"
            try:
                if manifest["kind"] == "RobotJob":
                    doc = {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name},
                           "spec": manifest["spec"]}
                    bed.api.create_namespaced_custom_object(GROUP, VERSION, bed.ns, ROBOTJOBS, doc)
                    if manifest["status"] and manifest["status_target"]:
                        bed.api.patch_namespaced_custom_object_status(
                            GROUP, VERSION, bed.ns, ROBOTJOBS, name, {"status": manifest["status"]})
                else:
                    cell = f"{name}-{bed.ns}"
                    doc = {"apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": cell},
                           "spec": manifest["spec"]}
                    bed.api.create_cluster_custom_object(GROUP, VERSION, CELLS, doc)
                    created_cells.append(cell)
            except ApiException as error:
                assert error.status == 422, f"{error.status}: {error.body}"
                assert names_its_field(error), f"a rejection that names no field: {error.body}"
                rejections.append(json.loads(error.body)["message"][:120])
            if index % PROBE_EVERY == 0:
                probe(controller)

        try:
            one()
            probe(controller)
        finally:
            for cell in created_cells:
                bed.k8s.kubectl("delete", "cell", cell, "--ignore-not-found", "--wait=false", check=False)
    print(f"{EXAMPLES} manifests, {len(rejections)} rejected by the API server; "
          f"probe binds {min(latencies):.2f}-{max(latencies):.2f}s")
