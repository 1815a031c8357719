"""Shell completion of job names: the generated bash function asks the real apiserver through ``armnet get -o name``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from armnet_cli.completion import bash_script, describe, full_parser
from armnet_core.models import JobSpec

from tests.integration.client_bed import Tenant

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]


def complete(line: str, workdir: Path, env: dict[str, str]) -> list[str]:
    source = workdir / "armnet.bash"
    source.write_text(bash_script(describe(full_parser())))
    words = line.split(" ")
    program = (f"source {source}\nCOMP_WORDS=({' '.join(repr(w) for w in words)})\nCOMP_CWORD={len(words) - 1}\n"
               '_armnet_complete\nprintf "%s\\n" "${COMPREPLY[@]}"\n')
    done = subprocess.run(["bash", "--norc", "--noprofile", "-c", program], capture_output=True, text=True,
                          cwd=workdir, env=env, timeout=120, check=True)
    return sorted(w for w in done.stdout.splitlines() if w)


@pytest.fixture
def shell_env(tmp_path: Path) -> dict[str, str]:
    """A PATH whose ``armnet`` is this worktree's CLI, as the installed console script would be."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    wrapper = bin_dir / "armnet"
    wrapper.write_text(f"#!/bin/sh\nexec {sys.executable} -m armnet_cli.main \"$@\"\n")
    wrapper.chmod(0o755)
    pythonpath = ":".join(str(REPO / p) for p in ("runtime/src", "agent", "operator", "cli")) + f":{REPO}"
    return {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "PYTHONPATH": pythonpath, "KUBECONFIG": ""}


def test_job_names_of_the_namespace_on_the_line_complete(
    k8s: Any, namespace: str, tmp_path: Path, shell_env: dict[str, str]
) -> None:
    tenant = Tenant(k8s, namespace)
    client = tenant.client()
    for name in ("pick-1", "pick-2", "place-1"):
        client.submit(JobSpec(image="localhost/pick:dev", embodiment="test/completion"), name=name)
    cluster = f"--kubeconfig {tenant.kubeconfig} -n {namespace}"

    assert complete(f"armnet logs {cluster} -f pi", tmp_path, shell_env) == ["pick-1", "pick-2"]
    assert complete(f"armnet cancel {cluster} ", tmp_path, shell_env) == ["pick-1", "pick-2", "place-1"]


def test_get_o_name_prints_one_robotjob_per_line(k8s: Any, namespace: str, capsys: pytest.CaptureFixture[str]) -> None:
    tenant = Tenant(k8s, namespace)
    tenant.client().submit(JobSpec(image="localhost/pick:dev", embodiment="test/completion"), name="only-one")

    assert tenant.cli("get", "-o", "name") == 0
    assert capsys.readouterr().out == "robotjob/only-one\n"
