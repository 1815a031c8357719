"""The cell operator's page in a real browser, over the real operator, agent, jobs and NATS.

Headless Chromium (Debian's, through chromedriver and selenium) drives
``armnet fms`` (a real process) while the real ``armnet operator`` and ``armnet
agent`` run real job containers on simulated cells (``AgentBed``). One bed for
the module: both jobs are submitted at the start and run side by side. The
window is a landscape tablet's (1024x768: 625 px of page in sight): each tap's
answer must show there, and no button may move or change meaning under a finger
(``tests/support/fms_tablet.py``). Screenshots of the fleet and cell views go to
``test-artifacts/``.
"""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from selenium.common.exceptions import TimeoutException
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as visible
from selenium.webdriver.support.ui import WebDriverWait

from e2e.agent_bed import AgentBed
from tests.support.fms_server import (
    OPERATOR,
    FmsServer,
    chromium,
    console_errors,
    log_in,
    screenshot,
)
from tests.support.fms_tablet import (
    VERDICTS,
    assert_in_first_screen,
    assert_nothing_moved,
    button_boxes,
    filter_labels,
    first_state_showing,
    on_a_tablet,
    open_card_with_the_keyboard,
    overlaps,
    tap,
    tap_card_away_from_its_name,
    watch_outcome_box,
)

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(900)]

RESETS_THEN_ROLLOUTS = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        ctx.cell.reset()  # waits for the cell operator's Confirm reset
        outcomes = []
        for index in (1, 2):
            ctx.cell.rollout_begin(index=index, total=2)
            while not (status := ctx.cell.is_complete()).complete:
                time.sleep(0.1)
            outcomes.append(status.success)
            ctx.cell.rollout_end()
        return {"outcomes": outcomes}
"""

WORKS_UNTIL_STOPPED = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        ctx.cell.rollout_begin(index=1, total=1, outcome_controls=False)
        while not ctx.cell.is_shutting_down():
            ctx.report_progress("sorting cubes")
            time.sleep(0.2)
        return {"stopped_cleanly": True}
"""


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str, nats_server: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("fms-e2e")
    bed = AgentBed(k8s, podman, base_image, namespace, nats_url=nats_server)
    bed.telemetry = True  # the cell page's camera and servo plots
    # A camera on each cell: a cell's page shows the simulator's picture and the servo plots.
    camera = {"front": {"indexOrPath": 0}}
    # The person at the robot gets minutes: a browser on a loaded 2-core host took over 30 s
    # (the bed's default) from the reset request to the click.
    bed.reset_cell = bed.add_cell("fms-a", cameras=camera, resetTimeoutSeconds=600)  # type: ignore[attr-defined]
    bed.stop_cell = bed.add_cell("fms-b", cameras=camera)  # type: ignore[attr-defined]
    bed.start_operator()
    bed.start_agent()
    try:
        for cell in (bed.reset_cell, bed.stop_cell):  # type: ignore[attr-defined]
            bed.wait_ready(cell, timeout=240)  # a loaded 2-core machine takes minutes
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


@pytest.fixture(scope="module")
def fms(bed: AgentBed, k8s: Any, nats_server: str) -> Iterator[FmsServer]:
    server = FmsServer(k8s.kubeconfig, nats_server)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def jobs(bed: AgentBed) -> dict[str, str]:
    """Both jobs, submitted together; each waits for the operator on its own cell."""
    return {
        "reset": bed.submit("resets-then-rollouts", bed.image("fms-resets", RESETS_THEN_ROLLOUTS), timeout=300),
        # Stopped by the test, never by its deadline: the first test may take minutes on a loaded host.
        "stop": bed.submit("works-until-stopped", bed.image("fms-stop", WORKS_UNTIL_STOPPED), timeout=1800),
    }


@pytest.fixture
def browser() -> Iterator[Any]:
    driver = chromium()
    yield driver
    driver.quit()


def cell_of(bed: AgentBed, job: str) -> str:
    st = bed.wait(lambda: (bed.job(job).get("status") or {}).get("cellName"), 180, f"{job} bound to a cell")
    return str(st)


def deadline_trips(bed: AgentBed) -> float:
    """The agent's ``armnet_agent_interlock_trips_total{reason="deadline"}``, from its metrics endpoint."""
    with urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10) as reply:
        text = reply.read().decode()
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines()
               if line.startswith('armnet_agent_interlock_trips_total{reason="deadline"}'))


def wait_text(driver: Any, element_id: str, text: str, timeout: float = 60,
              context: Callable[[], str] | None = None) -> None:
    """Wait for ``text`` in the element; on a timeout, say what it shows instead (and ``context``: the job's status)."""
    try:
        WebDriverWait(driver, timeout).until(visible.text_to_be_present_in_element((By.ID, element_id), text))
    except TimeoutException as exc:
        shown = driver.execute_script(f"return document.getElementById({element_id!r})?.textContent ?? '(absent)';")
        raise AssertionError(f"#{element_id} did not show {text!r} within {timeout} s; it shows {shown!r}"
                             + (f"\n{context()}" if context is not None else "")) from exc


def job_status(bed: AgentBed, name: str) -> Callable[[], str]:
    return lambda: f"job {name}: " + json.dumps(bed.job(name).get("status") or {})[:3000]


def tap_and_see_the_answer(driver: Any, element_id: str, answer: str) -> None:
    """Tap, then the answer shows in the tablet's first screen, in sight of the finger."""
    tap(driver, element_id)
    wait_text(driver, "action-result", answer)
    assert_in_first_screen(driver, element_id)
    assert_in_first_screen(driver, "action-result")


def telemetry_seen(driver: Any) -> dict[str, Any]:
    """The telemetry line and each plot's number of points, read in one render."""
    seen: dict[str, Any] = driver.execute_script(
        "return {text: document.getElementById('telemetry-state').textContent,"
        " points: Object.fromEntries([...document.querySelectorAll('svg.plot')]"
        "   .map((p) => [p.dataset.field, Number(p.dataset.points)])),"
        " captions: [...document.querySelectorAll('#plots figcaption')].map((c) => c.textContent)};")
    return seen


def test_the_fleet_updates_live_and_a_reset_then_two_outcomes_reach_the_job(
    bed: AgentBed, fms: FmsServer, jobs: dict[str, str], browser: Any
) -> None:
    cell = cell_of(bed, jobs["reset"])
    on_a_tablet(browser)
    log_in(browser, fms.url)
    # Live: the page was loaded before the job ran; it shows the job without a reload.
    wait_text(browser, f"cell-{cell}", jobs["reset"], timeout=180, context=job_status(bed, jobs["reset"]))
    wait_text(browser, f"cell-{cell}", "reset waiting", timeout=180, context=job_status(bed, jobs["reset"]))
    # The operator's summary of the queue at the cell (status.queue): none waits; the job's end, from its timeout.
    wait_text(browser, f"cell-{cell}", "0 jobs waiting; its job likely ends in", timeout=60,
              context=lambda: json.dumps((bed.cell(cell).get("status") or {}).get("queue")))
    assert filter_labels(browser) == {"filter-q": "Cell name", "filter-site": "Site"}
    screenshot(browser, "fms-fleet")
    # The whole card opens the cell, not only its name; and so does the keyboard (Tab, Enter).
    tap_card_away_from_its_name(browser, cell)
    WebDriverWait(browser, 30).until(lambda d: d.current_url == f"{fms.url}/cells/{cell}")
    browser.get(f"{fms.url}/")
    wait_text(browser, f"cell-{cell}", "reset waiting")
    open_card_with_the_keyboard(browser, cell)
    WebDriverWait(browser, 30).until(lambda d: d.current_url == f"{fms.url}/cells/{cell}")
    WebDriverWait(browser, 60).until(visible.element_to_be_clickable((By.ID, "confirm-reset")))
    wait_text(browser, "reset-left", "s left")
    screenshot(browser, "fms-cell-reset")
    # The job runs and has not opened the arm's bus: the line says what is not read, the plots draw none of it.
    wait_text(browser, "telemetry-state", "not plotted: the job has not connected this arm's bus")
    seen = telemetry_seen(browser)
    assert "arm arm" not in seen["text"] and "not read while a job runs" in seen["text"], seen
    assert seen["points"] == {"position": 0, "load": 0, "temperature": 0}, seen
    before = button_boxes(browser)
    watch_outcome_box(browser, before["confirm-reset"])
    tap_and_see_the_answer(browser, "confirm-reset", "reset confirmed")
    wait_text(browser, "outcome-rollout", "1/2")
    # Where Confirm reset was, no verdict button: a late second tap marks nothing; and Success/Fail
    # appeared unarmed (they ignore taps for a moment, whatever lies under the finger).
    first = first_state_showing(browser, "1/2")
    assert first["under"] not in VERDICTS and not first["underArmed"] and first["armed"] == [], first
    after = button_boxes(browser)
    assert not any(overlaps(before["confirm-reset"], after[v]) for v in VERDICTS), (before, after)
    assert_nothing_moved(before, after)
    screenshot(browser, "fms-cell")
    tap_and_see_the_answer(browser, "mark-fail", "rollout 1/2 marked failure")
    wait_text(browser, "outcome-rollout", "2/2")
    # Fail stays under the finger but means rollout 2 now: it was unarmed when it came to mean it.
    assert first_state_showing(browser, "2/2")["armed"] == [], first_state_showing(browser, "2/2")
    assert_nothing_moved(after, button_boxes(browser))
    wait_text(browser, "verdicts", f"Rollout 1/2: failure, marked by {OPERATOR}")  # the page reads status.rollouts
    tap_and_see_the_answer(browser, "mark-success", "rollout 2/2 marked success")
    job = bed.wait_phase(jobs["reset"], timeout=120)
    st = job["status"]
    assert st["phase"] == "succeeded", json.dumps(st)[:3000]
    assert st["result"]["returnValue"] == {"outcomes": [False, True]}
    # The agent recorded each rollout and its verdict with who marked it (status.rollouts).
    assert [(r["index"], r["total"], r["outcome"], r.get("markedBy")) for r in st["rollouts"]] == [
        (1, 2, "failure", OPERATOR), (2, 2, "success", OPERATOR)], json.dumps(st.get("rollouts"))
    assert all(r["startedAt"] <= r["markedAt"] <= r["endedAt"] for r in st["rollouts"])
    assert console_errors(browser) == []
    events = json.loads(bed.k8s.kubectl("get", "events", "-n", bed.namespace, "-o", "json").stdout)["items"]
    audit = [e["message"] for e in events if e["involvedObject"]["name"] == jobs["reset"]
             and e.get("reportingComponent") == "armnet-fms"]
    assert f"reset confirmed by cell operator {OPERATOR}" in audit
    assert f"rollout 1/2 marked failure by cell operator {OPERATOR}" in audit
    # The job over, the cell is idle: the agent reads its servos (all three quantities) and camera
    # itself, live on the page.
    WebDriverWait(browser, 120).until(lambda d: d.execute_script(
        "const img = document.getElementById('camera-front');"
        "const load = document.querySelector('svg.plot[data-field=load]');"
        "return !!img && img.naturalWidth > 0 && !!load && Number(load.dataset.points) > 0;"))
    assert all(points > 0 for points in telemetry_seen(browser)["points"].values()), telemetry_seen(browser)
    screenshot(browser, "fms-cell-idle")


def test_stop_cancels_the_job_trips_its_interlock_and_the_cell_is_ready_after(
    bed: AgentBed, fms: FmsServer, jobs: dict[str, str], browser: Any
) -> None:
    cell = cell_of(bed, jobs["stop"])
    bed.wait_phase(jobs["stop"], phases=("running",), timeout=180)
    on_a_tablet(browser)
    log_in(browser, fms.url)
    browser.get(f"{fms.url}/cells/{cell}")
    try:
        WebDriverWait(browser, 120).until(visible.element_to_be_clickable((By.ID, "stop")))
    except TimeoutException:
        status = bed.job(jobs["stop"]).get("status") or {}
        pytest.fail(f"no Stop button for {jobs['stop']} on {cell}; its status: {json.dumps(status)[:2000]}; "
                    f"the page at {browser.current_url}: {browser.page_source[:1500]}")
    # The first tap arms Stop for 5 s. Tapped and read in one script, in the page: on a loaded machine
    # a WebDriver round trip alone can outlast the 5 s, and the armed text was gone before it was read.
    before = button_boxes(browser)
    armed = browser.execute_script("const b = document.getElementById('stop'); b.click(); return b.textContent;")
    assert "Tap again" in armed, armed
    assert_nothing_moved(before, button_boxes(browser))  # the longer text moved nothing beside it
    # The arm lapses 5 s after the first tap: a stray tap later stops nothing.
    wait_text(browser, "stop", "Stop job")
    # A person's two taps come well within those 5 s; on a loaded machine one WebDriver round trip
    # can take that long (a second tap() after the checks above met a lapsed arm in CI and only armed
    # it again), so the two taps go to the browser in one actions command.
    button = browser.find_element(By.ID, "stop")
    ActionChains(browser).click(button).pause(0.3).click(button).perform()
    wait_text(browser, "action-result", f"stopped by cell operator {OPERATOR}")
    assert_in_first_screen(browser, "stop")
    assert_in_first_screen(browser, "action-result")
    st = bed.wait_phase(jobs["stop"], timeout=120)["status"]
    assert st["phase"] == "cancelled", json.dumps(st)[:3000]
    assert st["result"]["error"] == f"stopped by cell operator {OPERATOR}"
    # Graceful: the job saw is_shutting_down() (the grace window the interlock trip opens) and returned.
    assert st["result"].get("returnValue") == {"stopped_cleanly": True}, json.dumps(st)[:3000]
    # A cancel trips the interlock the way a deadline does; counted just after the status is written.
    bed.wait(lambda: deadline_trips(bed) >= 1, 10, "the cancel's interlock trip counted")

    def ready_again() -> bool:
        status = bed.cell(cell).get("status") or {}
        conditions = {c["type"]: c["status"] for c in status.get("conditions", [])}
        return status.get("phase") == "Ready" and conditions.get("InterlockClear") == "True"

    bed.wait(ready_again, 120, f"{cell} Ready with its interlock clear after the job")
    assert console_errors(browser) == []


def test_an_unauthenticated_browser_gets_the_login_page_and_no_data(
    bed: AgentBed, fms: FmsServer, browser: Any
) -> None:
    browser.get(f"{fms.url}/")
    assert browser.current_url.endswith("/login")
    assert bed.reset_cell not in browser.page_source  # type: ignore[attr-defined]
    browser.get(f"{fms.url}/api/fleet")
    assert "log in as a cell operator" in browser.page_source
    assert bed.reset_cell not in browser.page_source  # type: ignore[attr-defined]


def test_a_logged_in_browsers_post_without_the_csrf_token_is_refused(
    bed: AgentBed, fms: FmsServer, browser: Any
) -> None:
    cell = bed.stop_cell  # type: ignore[attr-defined]
    log_in(browser, fms.url)
    WebDriverWait(browser, 30).until(lambda d: d.current_url.rstrip("/") == fms.url)
    post = """
        const [cell, token, done] = arguments;
        const headers = {"Content-Type": "application/json"};
        if (token) headers["X-CSRF-Token"] = token;
        fetch(`/api/cells/${cell}/cordon`, {method: "POST", credentials: "same-origin", headers, body: "{}"})
          .then((r) => done(r.status), () => done(-1));
    """
    assert browser.execute_async_script(post, cell, "") == 403
    assert browser.execute_async_script(post, cell, "forged-token") == 403
    assert bed.cell(cell)["spec"].get("unschedulable", False) is False
