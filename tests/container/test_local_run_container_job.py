"""``armnet run --image``'s launcher against the real engine (Podman via the Docker API).

The job container is the test bed's base image with this machine's Python, venv
and repository mounted read-only (a development stand-in for a runtime image);
everything else is the production path: ``ContainerJob`` (explicit ulimits, the
run directory bind-mounted, host network), the real connector and simulator of a
``LocalCell``, and the shared supervisor following the container's log streams.
"""

from __future__ import annotations

import os
import sys
import tempfile
import textwrap
import threading
import time
from collections import Counter
from pathlib import Path

import pytest
from armnet_core import JobResult, JobStatus
from armnet_launch.cell_spec import build_job_env, resolve_spec
from armnet_launch.container import ContainerJob
from armnet_launch.sim_cell import LocalCell
from armnet_launch.supervise import JobHooks, SupervisorLimits, supervise
from armnet_testbed.plugin import Podman
from armnet_testbed.podman import ulimits

pytestmark = [pytest.mark.container, pytest.mark.timeout(600)]

REPO = Path(__file__).resolve().parents[2]
HOST_PYTHON_MOUNTS = {p: p for p in {sys.prefix, sys.base_prefix, str(REPO)}}


def run_in_container(podman: Podman, image: str, script: Path, timeout: int, grace: float) -> JobResult:
    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=grace)
    run_dir = Path(tempfile.mkdtemp(prefix="armnet-run-"))
    hooks = JobHooks()
    with LocalCell(spec, run_dir, on_grace_expired=hooks.kill_now.set) as cell:
        hooks.on_deadline = cell.pass_deadline
        env = build_job_env(spec, cell.layout, job_id="ctr-test", timeout_seconds=timeout, args={"x": 3})
        env.update(PATH=f"{sys.prefix}/bin:/usr/bin:/bin", PYTHONUNBUFFERED="1")
        job = ContainerJob.start(podman.client, image, script, env, run_dir, extra_mounts=HOST_PYTHON_MOUNTS)
        try:
            return supervise(job, SupervisorLimits(timeout_seconds=timeout, grace_seconds=grace), hooks)
        finally:
            job.remove()


def script(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "job.py"
    path.write_text(textwrap.dedent(body))
    return path


def test_a_container_job_returns_its_value_and_reaches_the_connector(
    podman: Podman, base_image: str, tmp_path: Path
) -> None:
    job = script(tmp_path, """
        from armnet_runtime import Context, main
        from armnet_runtime.transport import connector_request

        @main
        def run(ctx: Context):
            ctx.report_progress("inside the container")
            hello = connector_request(ctx.cell.robot_port, {"op": "hello"}, read_timeout=10)
            return {"x": ctx.args["x"], "socket": hello["socket"], "shutting_down": ctx.cell.is_shutting_down()}
    """)
    result = run_in_container(podman, base_image, job, timeout=240, grace=5)
    assert result.status is JobStatus.SUCCEEDED, f"{result}\n{result.stdout}\n{result.stderr}"
    assert result.return_value == {"x": 3, "socket": "robot", "shutting_down": False}
    assert "[armnet:progress] inside the container" in result.stdout


def test_a_raise_in_a_container_job_is_failed_with_its_traceback(
    podman: Podman, base_image: str, tmp_path: Path
) -> None:
    job = script(tmp_path, """
        from armnet_runtime import Context, main

        @main
        def run(ctx: Context):
            raise ValueError("boom from the container")
    """)
    result = run_in_container(podman, base_image, job, timeout=240, grace=5)
    assert result.status is JobStatus.FAILED
    assert result.exit_code == 1
    assert result.traceback is not None and "ValueError: boom from the container" in result.traceback


def test_a_container_ignoring_its_timeout_is_killed_at_the_end_of_the_grace_window(
    podman: Podman, base_image: str, tmp_path: Path
) -> None:
    job = script(tmp_path, """
        import time
        from armnet_runtime import Context, main

        @main
        def run(ctx: Context):
            print("ignoring the deadline", flush=True)
            while True:
                time.sleep(0.05)
    """)
    # 60 s: under three sessions on 2 cores the job's interpreter took over 40 s to start (quiet: ~3 s).
    timeout, grace = 60, 2.0
    result = run_in_container(podman, base_image, job, timeout=timeout, grace=grace)
    assert result.status is JobStatus.TIMEOUT, str(result)
    assert "ignoring the deadline" in result.stdout
    assert result.started_at is not None and result.finished_at is not None
    overrun = (result.finished_at - result.started_at).total_seconds() - (timeout + grace)
    assert 0 <= overrun < 1.0, f"killed {overrun:.3f} s after the grace window closed"


@pytest.mark.parametrize("grace", [0.0, ContainerJob.follow_grace_s])
def test_a_container_jobs_output_arrives_whole_and_once_even_when_the_follow_drops_or_stalls(
    podman: Podman, base_image: str, grace: float
) -> None:
    """50,000 fast lines: Podman 4.3's follow drops stretches of them as the container exits
    (measured: 30-45 %); with no grace it is also closed the moment the container exits."""
    lines = 50_000
    container = podman.client.containers.create(
        base_image, ["python3", "-c", f"import sys\nfor i in range({lines}): sys.stdout.write(f'line {{i}}\\n')"],
        network_mode="host", ulimits=podman.ulimits(), detach=True,
    )
    container.start()
    job = ContainerJob(podman.client, container)
    job.read_log_file = False  # the Docker API's follow: the fallback when the log file cannot be read
    job.follow_grace_s = grace
    try:
        output = b"".join(job.stdout_chunks()).decode()
        assert job.wait(60) == 0
    finally:
        job.remove()
    counts = Counter(output.splitlines())
    expected = [f"line {i}" for i in range(lines)]
    assert [line for line in expected if counts[line] != 1] == [], "every line exactly once"
    # Podman may cut a line while dropping a stretch; such a fragment reaches the reader as
    # well (it cannot be taken back), next to the whole line.
    fragments = set(counts) - set(expected)
    assert len(fragments) <= 5, f"fragments: {sorted(fragments)[:10]}"


def test_an_exit_burst_read_from_the_log_file_arrives_complete_and_in_order_on_each_stream(
    podman: Podman, base_image: str
) -> None:
    """50,000 lines printed as fast as Python can, the container exiting right after; every
    100th line also goes to stderr, so the records of both streams interleave in the file."""
    lines = 50_000
    printer = (
        "import sys\n"
        f"for i in range({lines}):\n"
        "    sys.stdout.write(f'line {i}\\n')\n"
        "    if i % 100 == 0: sys.stderr.write(f'err {i}\\n')\n"
    )
    container = podman.client.containers.create(
        base_image, ["python3", "-c", printer], network_mode="host", ulimits=podman.ulimits(), detach=True,
    )
    container.start()
    job = ContainerJob(podman.client, container)
    try:
        assert job.log_file is not None, "Podman's k8s-file log is read directly on this host"
        stderr: list[bytes] = []
        reader = threading.Thread(target=lambda: stderr.extend(job.stderr_chunks()))
        reader.start()
        stdout = b"".join(job.stdout_chunks()).decode()
        reader.join(60)
        assert job.wait(60) == 0
    finally:
        job.remove()
    assert stdout.splitlines() == [f"line {i}" for i in range(lines)]
    assert b"".join(stderr).decode().splitlines() == [f"err {i}" for i in range(0, lines, 100)]


def test_the_engine_is_asked_what_it_is_once_per_client_and_reads_its_log_file(podman: Podman) -> None:
    """Podman answers ``/version`` with a package-manager query per component: once per client."""
    from armnet_launch import container as launch_container

    asked = Counter[str]()
    real_version = podman.client.version

    def counted_version() -> dict[str, object]:
        asked["version"] += 1
        return dict(real_version())

    podman.client.version = counted_version
    try:
        launch_container._ENGINE_KINDS.pop(podman.client, None)
        kinds = [launch_container._engine_kind(podman.client) for _ in range(3)]
    finally:
        del podman.client.version
    assert kinds == [("podman", "")] * 3
    assert asked["version"] == 1


def test_the_engine_is_asked_for_the_exit_code_only_once_the_containers_init_has_ended(
    podman: Podman, base_image: str, tmp_path: Path
) -> None:
    """Podman 4.3's Docker API answers a wait by polling in a loop (a core of its CPU while the job
    runs): the launcher blocks on a pidfd of the container's init and asks the engine afterwards."""
    from armnet_launch.plan import ContainerSpec, Mount

    asked_for: list[str] = []
    real_wait = podman.client.api.wait

    def watched_wait(container: str, *args: object, **kwargs: object) -> dict[str, object]:
        asked_for.append(container)
        return dict(real_wait(container, *args, **kwargs))

    podman.client.api.wait = watched_wait
    try:
        held = "while [ ! -e /hold/go ]; do sleep 0.1; done; exit 7"
        spec = ContainerSpec(image=base_image, env={}, command=("sh", "-c", held),
                             mounts=(Mount(str(tmp_path), "/hold"),))
        job = ContainerJob.launch(podman.client, spec)
        try:
            assert job.waits_on_pidfd
            time.sleep(2.0)  # the old launcher's waiting thread asked the engine at once
            assert job.container_id not in asked_for, "the engine was asked to wait while the job ran"
            (tmp_path / "go").write_text("")
            assert job.wait(60) == 7
            assert job.container_id in asked_for
        finally:
            job.remove()
    finally:
        del podman.client.api.wait


def test_a_pid_is_a_containers_only_when_the_process_is_in_its_cgroup(podman: Podman, base_image: str) -> None:
    """The engine's pid is taken for a kill only when it names the container's own process here."""
    from armnet_launch.container import container_pidfd, process_in_container

    container = podman.client.containers.run(base_image, ["sleep", "30"], detach=True, ulimits=ulimits(),
                                             network_mode="host")
    try:
        container.reload()
        pid = int(container.attrs["State"]["Pid"])
        assert process_in_container(pid, container.id)
        assert not process_in_container(os.getpid(), container.id)
        assert not process_in_container(pid, container.id[:12]), "a short id would match too much"
        assert not process_in_container(pid, "f" * 64)
        held = container_pidfd(pid, container.id)
        assert held is not None
        os.close(held)
        assert container_pidfd(os.getpid(), container.id) is None, "a process outside the container"
        assert container_pidfd(0, container.id) is None
    finally:
        container.remove(force=True)
