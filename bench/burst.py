"""500 RobotJobs applied at once, from one or many tenants: exact queue positions, a bind elsewhere, operator memory.

The operator under a burst, with every object checked as hostile input, measured
against the test bed's real kube-apiserver with ``armnet operator`` in its own
process, for one or more source trees in the same run (``--tree ../armnet-before
--tree .``: the code before and after a change, alternated ``--rounds`` times on
one control plane).

Per run: one cell of embodiment A (it takes one job; the rest must queue), one
free cell of embodiment B. The bench creates N jobs for A from 16 threads, spread
round-robin over ``--tenants`` namespaces, and, once a quarter of them are in, one
job for B in the first namespace. The operator watches exactly those namespaces.

With ``--tenants 1`` (the default) there is no CellQuota: every job belongs to the
one unmanaged tenant. With T > 1 each namespace is a tenant with a CellQuota for
embodiment A, tenant i in cohort i % ``--cohorts``. Tenant 0 owns the one cell of
A (``nominalCells: 1``); every other tenant has ``nominalCells: 0`` and may borrow
idle nominal cells of its cohort (no ``borrowingLimit``), so only tenant 0 and its
cohort peers can ever take the cell, and once it is held every other A job waits
with a reason (``QuotaExhausted``: no idle cell in its cohort). Should a cohort
peer of tenant 0 bind first, tenant 0's jobs wait as ``AllCellsBusy`` and the
operator asks the borrower to give the cell back (the bench prints which job was
bound and any such request). A rationed namespace runs no job its quotas do not
cover, so tenant 0 also gets a CellQuota for B (``nominalCells: 1``) for B's job.

It reports

- queued: time until every A job but the bound one has ``phase: queued`` and a
  ``queuePosition`` (any position: the figure before tenants were added),
- exact: time until, in addition, the positions the operator wrote are exact. The
  operator numbers the waiting jobs of an embodiment (jobs without a task) in one
  queue across all tenants (``scheduling._positions``), so the waiting A jobs'
  positions must be 1..M, M their number, each once. Both figures from the first
  and from the last create (target: exact within 3 s of the last create). At the
  end it also checks that within each tenant positions follow submission order
  (creation time, then name: the tenant's FIFO),
- the B job's submit->bound during the burst (target: < 1 s),
- the operator's peak resident memory (VmHWM; target: < 128 MiB).

Usage: ``~/.cache/armnet/venv/bin/python bench/burst.py --tree ../armnet-before --tree . [--jobs 500] [--rounds 2]
[--tenants 20 --cohorts 10]``.
The 2-core VM is shared: figures vary with its load; compare trees within one run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
import uuid
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from armnet_core.api import API_VERSION, CELLQUOTAS, CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_core.times import kube_time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def stamp() -> str:
    return kube_time(datetime.now(UTC))


def peak_rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def create_tenants(plane: Any, api: Any, tag: str, emb_a: str, emb_b: str, tenants: int, cohorts: int) -> list[str]:
    """The tenants' namespaces; with more than one, each with its CellQuota (see the module docstring)."""
    if tenants == 1:
        return [plane.create_namespace("burst")]
    namespaces = [plane.create_namespace(f"burst-t{i:02d}") for i in range(tenants)]
    quotas = [(f"burst-{tag}-t{i:02d}", {"namespace": ns, "embodiment": emb_a, "nominalCells": 1 if i == 0 else 0,
                                         "cohort": f"burst-{tag}-c{i % cohorts}", "weight": 1})
              for i, ns in enumerate(namespaces)]
    quotas.append((f"burst-{tag}-t00-b", {"namespace": namespaces[0], "embodiment": emb_b, "nominalCells": 1}))
    for name, spec in quotas:
        api.create_cluster_custom_object(GROUP, VERSION, CELLQUOTAS, {
            "apiVersion": API_VERSION, "kind": "CellQuota", "metadata": {"name": name}, "spec": spec})
    return namespaces


@dataclass
class Follower:
    """What the watch saw of the run's jobs, and when the A queue first had exact positions."""

    namespaces: frozenset[str]
    a_jobs: frozenset[str]
    queued_at: dict[str, float] = field(default_factory=dict)
    bound_at: dict[str, float] = field(default_factory=dict)
    position: dict[str, int] = field(default_factory=dict)
    """Each waiting A job's written queuePosition (jobs in phase queued only)."""
    held: Counter[int] = field(default_factory=Counter)
    """How many waiting A jobs hold each position."""
    reasons: dict[str, str] = field(default_factory=dict)
    created: dict[str, str] = field(default_factory=dict)
    preemption_requests: set[str] = field(default_factory=set)
    exact_at: float | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def see(self, obj: dict[str, Any]) -> None:
        meta = obj["metadata"]
        if meta.get("namespace") not in self.namespaces:
            return
        key = f"{meta['namespace']}/{meta['name']}"
        status = obj.get("status") or {}
        now = time.perf_counter()
        with self.lock:
            phase, position = status.get("phase"), status.get("queuePosition")
            if phase == "queued" and position and key not in self.queued_at:
                self.queued_at[key] = now
            if phase == "dispatched" and key not in self.bound_at:
                self.bound_at[key] = now
            if status.get("preemption"):
                self.preemption_requests.add(key)
            if key not in self.a_jobs:
                return
            self.created[key] = meta.get("creationTimestamp", "")
            self.reasons[key] = status.get("queuedReason") or phase or ""
            old = self.position.pop(key, None)
            if old is not None:
                self.held[old] -= 1
                if not self.held[old]:
                    del self.held[old]
            if phase == "queued" and isinstance(position, int) and position > 0:
                self.position[key] = position
                self.held[position] += 1
            if self.exact_at is None and self.exact():
                self.exact_at = now

    def exact(self) -> bool:
        """Every A job bound or queued, the queued ones at positions 1..M, each once (caller holds the lock)."""
        waiting = len(self.a_jobs) - sum(1 for k in self.bound_at if k in self.a_jobs)
        return (0 < waiting == len(self.position) == len(self.held)
                and max(self.held) == waiting and len(self.a_jobs) - waiting >= 1)

    def fifo_breaks(self) -> int:
        """Pairs of consecutive positions within a tenant out of submission order (caller holds the lock)."""
        by_tenant: dict[str, list[str]] = defaultdict(list)
        for key in self.position:
            by_tenant[key.split("/")[0]].append(key)
        breaks = 0
        for keys in by_tenant.values():
            keys.sort(key=self.position.__getitem__)
            order = [(self.created[k], k) for k in keys]
            breaks += sum(1 for a, b in zip(order, order[1:], strict=False) if a > b)
        return breaks


def one_run(plane: Any, tree: Path, n_jobs: int, tenants: int, cohorts: int) -> dict[str, Any]:
    from kubernetes import client, watch

    api = client.CustomObjectsApi(plane.api_client())
    tag = uuid.uuid4().hex[:6]
    emb_a, emb_b = f"burst-a/{tag}", f"burst-b/{tag}"
    namespaces = create_tenants(plane, api, tag, emb_a, emb_b, tenants, cohorts)
    for name, emb in ((f"a-{tag}", emb_a), (f"b-{tag}", emb_b)):
        api.create_cluster_custom_object(GROUP, VERSION, CELLS, {
            "apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name},
            "spec": {"embodiment": emb, "nodeName": "burst-host"}})
        api.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, name, {"status": {"lastHeartbeatTime": stamp()}})
    env = {**os.environ, "KUBECONFIG": str(plane.kubeconfig),
           "PYTHONPATH": ":".join(str(tree / p) for p in ("runtime/src", "agent", "operator", "cli", "."))}
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(plane.kubeconfig),
            "--namespaces", ",".join(namespaces), "--lease-namespace", namespaces[0], "--metrics-port", "0",
            "--heartbeat-timeout", "120", "--reconcile-period", "1", "--position-refresh", "5"]
    log_path = Path("/tmp") / f"armnet-burst-{tag}.log"
    log = log_path.open("w")
    operator = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tree)
    jobs = [(namespaces[i % tenants], f"a-{i:04d}") for i in range(n_jobs)]
    probe = (namespaces[0], "b-probe")
    seen = Follower(frozenset(namespaces), frozenset(f"{ns}/{name}" for ns, name in jobs))
    stop = threading.Event()

    def follow() -> None:
        while not stop.is_set():
            try:
                stream()
            except Exception as error:  # noqa: BLE001 - restart the watch (410 Gone, a timeout)
                if stop.is_set():
                    return
                print(f"    (bench watch restarted: {type(error).__name__}: {error})", flush=True)
                time.sleep(0.2)

    def stream() -> None:
        # One watch over all namespaces (earlier runs' namespaces are filtered out).
        w = watch.Watch()
        for event in w.stream(api.list_cluster_custom_object, GROUP, VERSION, ROBOTJOBS, timeout_seconds=300):
            seen.see(event["object"])
            if stop.is_set():
                w.stop()
                return

    threading.Thread(target=follow, daemon=True).start()
    try:
        deadline = time.monotonic() + 60
        while "Initial authentication has finished" not in log_path.read_text() or not Path(
                f"/proc/{operator.pid}").exists():
            if operator.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"operator from {tree} did not start; see {log_path}")
            time.sleep(0.2)
        time.sleep(2)  # the Lease and the first pass
        pool = ThreadPoolExecutor(16)
        created: dict[str, float] = {}

        def create(ns: str, name: str, emb: str) -> None:
            api.create_namespaced_custom_object(GROUP, VERSION, ns, ROBOTJOBS, {
                "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name},
                "spec": {"image": "localhost/bench:dev", "embodiment": emb}})
            created[f"{ns}/{name}"] = time.perf_counter()

        started = time.perf_counter()
        futures = [pool.submit(create, ns, name, emb_a) for ns, name in jobs[: n_jobs // 4]]
        b_submitted = time.perf_counter()
        futures.append(pool.submit(create, *probe, emb_b))
        futures += [pool.submit(create, ns, name, emb_a) for ns, name in jobs[n_jobs // 4:]]
        for f in futures:
            f.result()
        last_create = max(created.values())
        probe_key = "/".join(probe)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if seen.exact_at is not None and probe_key in seen.bound_at:
                break
            time.sleep(0.05)
        stop.set()
        with seen.lock:
            all_queued = max(seen.queued_at.get(k, seen.bound_at.get(k, float("inf"))) for k in seen.a_jobs)
            exact_at = float("inf") if seen.exact_at is None else seen.exact_at
            result = {
                "creates_s": last_create - started,
                "queued_after_first_create_s": all_queued - started,
                "queued_after_last_create_s": all_queued - last_create,
                "exact_after_first_create_s": exact_at - started,
                "exact_after_last_create_s": exact_at - last_create,
                "b_bind_s": seen.bound_at.get(probe_key, float("inf")) - b_submitted,
                "peak_rss_mib": peak_rss_mib(operator.pid),
                "alive": operator.poll() is None,
                "queued": len(seen.queued_at), "bound": len(seen.bound_at),
                "bound_a": sorted(k for k in seen.bound_at if k in seen.a_jobs),
                "exact_now": seen.exact(),
                "fifo_breaks": seen.fifo_breaks(),
                "reasons": Counter(seen.reasons[k] for k in seen.position),
                "preemption_requests": sorted(seen.preemption_requests),
                "log": log_path,
            }
        pool.shutdown(wait=False, cancel_futures=True)
        return result
    finally:
        operator.terminate()
        try:
            operator.wait(30)
        except subprocess.TimeoutExpired:
            operator.kill()
        log.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", action="append", type=Path, help="source tree of the operator (repeat)")
    parser.add_argument("--jobs", type=int, default=500)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--tenants", type=int, default=1,
                        help="namespaces the jobs are spread over; more than 1: each with a CellQuota")
    parser.add_argument("--cohorts", type=int, default=1, help="cohorts of the tenants' CellQuotas (tenant i in i %% K)")
    args = parser.parse_args()
    if not 1 <= args.cohorts <= args.tenants or args.jobs < 2 * args.tenants:
        parser.error("need 1 <= --cohorts <= --tenants and at least two jobs per tenant")
    trees = [t.resolve() for t in (args.tree or [REPO])]
    from armnet_testbed.kube import ControlPlane

    plane = ControlPlane().start()
    try:
        quotas = f", CellQuotas in {args.cohorts} cohort(s)" if args.tenants > 1 else ", no CellQuota"
        print(f"{args.jobs} RobotJobs applied at once (16 threads) from {args.tenants} tenant(s){quotas}; "
              f"load average {os.getloadavg()[0]:.1f}")
        print(f"{'tree':<28} {'creates s':>9} {'queued s':>9} {'after last':>10} {'exact s':>8} {'after last':>10} "
              f"{'B bind s':>9} {'RSS MiB':>8}")
        for _ in range(args.rounds):
            for tree in trees:
                r = one_run(plane, tree, args.jobs, args.tenants, args.cohorts)
                print(f"{str(tree)[-28:]:<28} {r['creates_s']:>9.2f} {r['queued_after_first_create_s']:>9.2f} "
                      f"{r['queued_after_last_create_s']:>10.2f} {r['exact_after_first_create_s']:>8.2f} "
                      f"{r['exact_after_last_create_s']:>10.2f} {r['b_bind_s']:>9.2f} {r['peak_rss_mib']:>8.1f}"
                      + ("" if r["alive"] else "  (operator exited)")
                      + ("" if r["queued"] + r["bound"] >= args.jobs + 1
                         else f"  (only {r['queued']:.0f} queued, {r['bound']:.0f} bound)"), flush=True)
                reasons = ", ".join(f"{reason} {count}" for reason, count in sorted(r["reasons"].items()))
                print(f"    A bound: {', '.join(r['bound_a']) or 'none'}; waiting: {reasons}; positions exact at "
                      f"the end: {'yes' if r['exact_now'] else 'NO'}; out of FIFO within a tenant: "
                      f"{r['fifo_breaks']}; reclaims asked: {len(r['preemption_requests'])}; log {r['log']}",
                      flush=True)
        print("targets: every job queued with its exact position within 3 s of the last create, the other cell's "
              "job bound within 1 s, operator memory under 128 MiB")
    finally:
        plane.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
