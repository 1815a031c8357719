"""500 RobotJobs applied at once: queue positions, a bind elsewhere during the burst, operator memory.

The operator under a burst, with every object checked as hostile input, measured
against the test bed's real kube-apiserver with ``armnet operator`` in its own
process, for one or more source trees in the same run (``--tree ../armnet-before
--tree .``: the code before and after a change, alternated ``--rounds`` times on
one control plane).

Per run: one cell of embodiment A (it takes one job; the rest must queue), one
free cell of embodiment B. The bench creates N jobs for A from 16 threads and,
once a quarter of them are in, one job for B. It reports

- queued: time from the first create until every A job but the bound one has
  ``phase: queued`` and a ``queuePosition`` (target: within 3 s of the last create),
- the B job's submit->bound during the burst (target: < 1 s),
- the operator's peak resident memory (VmHWM; target: < 128 MiB).

Usage: ``~/.cache/armnet/venv/bin/python bench/burst.py --tree ../armnet-before --tree . [--jobs 500] [--rounds 2]``.
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
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path

from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, VERSION
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


def one_run(plane, tree: Path, n_jobs: int) -> dict[str, float]:
    from kubernetes import client, watch

    api = client.CustomObjectsApi(plane.api_client())
    ns = plane.create_namespace("burst")
    tag = uuid.uuid4().hex[:6]
    emb_a, emb_b = f"burst-a/{tag}", f"burst-b/{tag}"
    for name, emb in ((f"a-{tag}", emb_a), (f"b-{tag}", emb_b)):
        api.create_cluster_custom_object(GROUP, VERSION, CELLS, {
            "apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name},
            "spec": {"embodiment": emb, "nodeName": "burst-host"}})
        api.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, name, {"status": {"lastHeartbeatTime": stamp()}})
    env = {**os.environ, "KUBECONFIG": str(plane.kubeconfig),
           "PYTHONPATH": ":".join(str(tree / p) for p in ("runtime/src", "agent", "operator", "cli", "."))}
    argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(plane.kubeconfig),
            "--namespaces", ns, "--lease-namespace", ns, "--metrics-port", "0", "--heartbeat-timeout", "120",
            "--reconcile-period", "1", "--position-refresh", "5"]
    log_path = Path("/tmp") / f"armnet-burst-{tag}.log"
    log = log_path.open("w")
    operator = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tree)
    queued_at: dict[str, float] = {}
    bound_at: dict[str, float] = {}
    stop = threading.Event()

    def follow() -> None:
        while not stop.is_set():
            try:
                stream()
            except Exception as error:  # noqa: BLE001 - restart the watch (410 Gone, a timeout)
                print(f"    (bench watch restarted: {type(error).__name__}: {error})", flush=True)
                time.sleep(0.2)

    def stream() -> None:
        w = watch.Watch()
        for event in w.stream(api.list_namespaced_custom_object, GROUP, VERSION, ns, ROBOTJOBS, timeout_seconds=300):
            status = event["object"].get("status") or {}
            name = event["object"]["metadata"]["name"]
            if status.get("phase") == "queued" and status.get("queuePosition") and name not in queued_at:
                queued_at[name] = time.perf_counter()
            if status.get("phase") == "dispatched" and name not in bound_at:
                bound_at[name] = time.perf_counter()
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

        def create(name: str, emb: str) -> None:
            api.create_namespaced_custom_object(GROUP, VERSION, ns, ROBOTJOBS, {
                "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name},
                "spec": {"image": "localhost/bench:dev", "embodiment": emb}})
            created[name] = time.perf_counter()

        names = [f"a-{i:04d}" for i in range(n_jobs)]
        started = time.perf_counter()
        futures = [pool.submit(create, n, emb_a) for n in names[: n_jobs // 4]]
        b_submitted = time.perf_counter()
        futures.append(pool.submit(create, "b-probe", emb_b))
        futures += [pool.submit(create, n, emb_a) for n in names[n_jobs // 4:]]
        for f in futures:
            f.result()
        last_create = max(created.values())
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            waiting = [n for n in names if n not in queued_at and n not in bound_at]
            if not waiting and "b-probe" in bound_at:
                break
            time.sleep(0.05)
        all_queued = max(queued_at.get(n, bound_at.get(n, float("inf"))) for n in names)
        result = {
            "creates_s": last_create - started,
            "queued_after_first_create_s": all_queued - started,
            "queued_after_last_create_s": all_queued - last_create,
            "b_bind_s": bound_at.get("b-probe", float("inf")) - b_submitted,
            "peak_rss_mib": peak_rss_mib(operator.pid),
            "alive": float(operator.poll() is None),
            "queued": len(queued_at), "bound": len(bound_at),
        }
        stop.set()
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
    args = parser.parse_args()
    trees = [t.resolve() for t in (args.tree or [REPO])]
    from armnet_testbed.kube import ControlPlane

    plane = ControlPlane().start()
    try:
        print(f"{args.jobs} RobotJobs applied at once (16 threads); load average {os.getloadavg()[0]:.1f}")
        print(f"{'tree':<28} {'creates s':>9} {'queued s':>9} {'after last':>10} {'B bind s':>9} {'RSS MiB':>8}")
        for _ in range(args.rounds):
            for tree in trees:
                r = one_run(plane, tree, args.jobs)
                print(f"{str(tree)[-28:]:<28} {r['creates_s']:>9.2f} {r['queued_after_first_create_s']:>9.2f} "
                      f"{r['queued_after_last_create_s']:>10.2f} {r['b_bind_s']:>9.2f} {r['peak_rss_mib']:>8.1f}"
                      + ("" if r["alive"] else "  (operator exited)")
                      + ("" if r["queued"] + r["bound"] >= args.jobs + 1
                         else f"  (only {r['queued']:.0f} queued, {r['bound']:.0f} bound)"), flush=True)
        print("targets: every job queued with a position within 3 s, the other cell's job bound within 1 s, "
              "operator memory under 128 MiB")
    finally:
        plane.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
