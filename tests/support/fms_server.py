"""``armnet fms`` as a real process for tests, and a headless Chromium (selenium) to drive its page.

The service runs from this worktree (``python -m armnet_cli.main fms``) with an
operators file (what the auth Secret holds), a session key and the test bed's
kubeconfig and NATS. Chromium and chromedriver come from Debian
(``scripts/setup.d/20-system.sh``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from armnet_testbed.procs import free_port

REPO = Path(__file__).resolve().parents[2]
PYTHONPATH = ":".join(str(REPO / p) for p in ("runtime/src", "agent", "operator", "cli", "fms")) + f":{REPO}"
OPERATOR, TOKEN = "maria", "maria-token-0123456789"
ARTIFACTS = REPO / "test-artifacts"


class FmsServer:
    """One ``armnet fms`` process; ``.url``; ``.log()`` for failure messages."""

    def __init__(self, kubeconfig: str | Path, nats_url: str, *extra: str, env: dict[str, str] | None = None) -> None:
        """``env``: more of the service's environment (the object store's ``ARMNET_ARTIFACTS_*``)."""
        self.dir = Path(tempfile.mkdtemp(prefix="armnet-fms-"))
        (self.dir / "operators").write_text(f"# the auth Secret\n{OPERATOR}:{TOKEN}\n")
        (self.dir / "session-key").write_text("0123456789abcdef0123456789abcdef")
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        argv = [sys.executable, "-m", "armnet_cli.main", "fms", "--host", "127.0.0.1", "--port", str(self.port),
                "--kubeconfig", str(kubeconfig), "--nats-url", nats_url,
                "--operators-file", str(self.dir / "operators"), "--session-key-file", str(self.dir / "session-key"),
                "--poll-interval", "0.5", "--insecure-cookies", *extra]
        self._log = open(self.dir / "fms.log", "ab")  # noqa: SIM115 - kept open for the process
        self.process = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                        env={**os.environ, **(env or {}), "PYTHONPATH": PYTHONPATH})
        self._wait_up()

    def _wait_up(self, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise AssertionError(f"armnet fms exited {self.process.returncode}:\n{self.log()}")
            try:
                with urllib.request.urlopen(f"{self.url}/healthz", timeout=2) as reply:
                    if reply.status == 200:
                        return
            except OSError:
                pass
            time.sleep(0.2)
        raise AssertionError(f"armnet fms did not come up in {timeout} s:\n{self.log()}")

    def log(self) -> str:
        return (self.dir / "fms.log").read_text(errors="replace")[-6000:]

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        self._log.close()
        shutil.rmtree(self.dir, ignore_errors=True)


def chromium() -> Any:
    """A headless Chromium through Debian's chromedriver, with the browser console log kept."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    for binary in ("/usr/bin/chromium", "/usr/bin/chromedriver"):
        if not Path(binary).exists():
            raise AssertionError(f"{binary} is missing: run scripts/setup.d/20-system.sh (apt: chromium chromium-driver)")
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                 "--window-size=1024,1366", "--disable-extensions"):  # a tablet's portrait screen
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def console_errors(driver: Any) -> list[str]:
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def log_in(driver: Any, base_url: str, token: str = TOKEN) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(f"{base_url}/login")
    driver.find_element(By.ID, "token").send_keys(token)
    driver.find_element(By.ID, "login").click()
    # The session cookie arrives with the redirect to the fleet page: a page asked for before
    # then is asked for without it (and answered with the login page).
    WebDriverWait(driver, 60).until(lambda d: d.find_elements(By.ID, "cells"))


def screenshot(driver: Any, name: str) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    driver.save_screenshot(str(path))
    return path
