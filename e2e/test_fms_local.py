"""``armnet run --fms``: the cell operator's page for a local simulated cell, clicked through in a browser.

The job runs on the local simulated cell exactly as ``armnet run`` runs it
(``run_local_job``, in a thread); headless Chromium logs in with the run's
token, confirms the job's reset, sees the camera and servo plots of what the
job reads, and marks its two rollouts.
"""

from __future__ import annotations

import argparse
import io
import shutil
import textwrap
import threading
from pathlib import Path

import pytest
from armnet_core import JobResult, JobStatus
from armnet_local.cli import add_arguments, parse_request, run_local_job
from armnet_local.render import TerminalRenderer
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as visible
from selenium.webdriver.support.ui import WebDriverWait

from e2e.agent_bed import EXAMPLES
from tests.support.fms_server import chromium, console_errors, free_port, log_in
from tests.support.fms_tablet import tap

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(900)]

#: The job's own timeout outlasts every wait of the test together (60 + 300 + 60 + 60 + 30 + 60 + 120 s):
#: with 300 s, a loaded run's slow steps let the job's timeout, not what the test checks, end it.
JOB_TIMEOUT_S = 720

# Reads the arm and its camera while it waits for the operator: the page plots and shows those.
JOB = """
    import time
    from _so101_moves import open_bus
    from armnet_runtime import Context, main
    from lerobot.cameras.opencv import OpenCVCamera

    @main
    def run(ctx: Context):
        ctx.cell.reset()
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        camera = OpenCVCamera(ctx.camera_configs["front"])
        camera.connect()
        outcomes = []
        try:
            for index in (1, 2):
                ctx.cell.rollout_begin(index=index, total=2)
                while not (status := ctx.cell.is_complete()).complete:
                    bus.sync_read("Present_Position")
                    camera.async_read(timeout_ms=1000)
                    time.sleep(0.1)
                outcomes.append(status.success)
                ctx.cell.rollout_end()
        finally:
            camera.disconnect()
            bus.disconnect(disable_torque=False)
        return {"outcomes": outcomes}
"""


def test_a_customer_confirms_a_reset_and_marks_rollouts_on_the_local_page(tmp_path: Path) -> None:
    script = tmp_path / "job.py"
    script.write_text(textwrap.dedent(JOB))
    shutil.copy(EXAMPLES / "_so101_moves.py", tmp_path)
    port = free_port()
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    request = parse_request(parser.parse_args([str(script), "--fms", str(port), "--timeout", str(JOB_TIMEOUT_S)]))
    err = io.StringIO()
    results: list[JobResult] = []
    runner = threading.Thread(target=lambda: results.append(run_local_job(request, TerminalRenderer(io.StringIO(), err))),
                              daemon=True)
    runner.start()
    token = wait_for_token(err)
    driver = chromium()
    try:
        log_in(driver, f"http://127.0.0.1:{port}", token)
        driver.get(f"http://127.0.0.1:{port}/cells/local")
        tap(driver, "confirm-reset", timeout=300)  # SDK imports and the rest pose: minutes on a loaded machine
        WebDriverWait(driver, 60).until(visible.text_to_be_present_in_element((By.ID, "outcome-rollout"), "1/2"))
        # The camera the job opened and the positions of its own reads, through the agent's telemetry code.
        WebDriverWait(driver, 60).until(lambda d: d.execute_script(
            "const img = document.getElementById('camera-front');"
            "const plot = document.querySelector('svg.plot');"
            "return !!img && img.naturalWidth > 0 && !!plot && Number(plot.dataset.points) > 0;"))
        WebDriverWait(driver, 30).until(visible.text_to_be_present_in_element((By.ID, "telemetry-state"),
                                                                               "job's own reads"))
        # Positions only: the plots draw no line of the load and temperature the line says are not read.
        seen = driver.execute_script(
            "return {text: document.getElementById('telemetry-state').textContent,"
            " points: Object.fromEntries([...document.querySelectorAll('svg.plot')]"
            "   .map((p) => [p.dataset.field, Number(p.dataset.points)]))};")
        assert "load and temperature are not read while a job runs" in seen["text"], seen
        assert seen["points"]["position"] > 0 and seen["points"]["load"] == seen["points"]["temperature"] == 0, seen
        tap(driver, "mark-fail")
        WebDriverWait(driver, 60).until(visible.text_to_be_present_in_element((By.ID, "outcome-rollout"), "2/2"))
        # Checked before the last click: the run ends with it, and its page server with it (the page's
        # next telemetry poll then fails, as it should).
        assert console_errors(driver) == []
        tap(driver, "mark-success")
        runner.join(120)
    finally:
        driver.quit()
    assert results, f"the run had not ended 120 s after the last verdict:\n{err.getvalue()}"
    (result,) = results
    assert result.status is JobStatus.SUCCEEDED, f"{result}\n{err.getvalue()}"
    assert result.return_value == {"outcomes": [False, True]}


def wait_for_token(err: io.StringIO, timeout: float = 60) -> str:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in err.getvalue().splitlines():
            if "the cell operator's page:" in line:
                return line.rsplit("token ", 1)[1].rstrip(")")
        time.sleep(0.1)
    raise AssertionError(f"armnet run --fms printed no page address:\n{err.getvalue()}")
