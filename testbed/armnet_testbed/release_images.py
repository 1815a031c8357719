"""The images the chart's real install runs on the test-bed node, ready in its store before the tests.

tests/images/test_helm_install_node.py installs the chart with ``pullPolicy: Never``, so the
node's containerd must hold the operator and agent images under one tag (the chart has one
``image.tag``), the example customer image (images/example-job, on the runtime image), and two
customer images on the runtime's LeRobot variant: the bus-loop example and the unattended
evaluation (e2e/jobs/unattended_eval.py: scored, reset, scored with nobody at the cell). The LeRobot images are ~6 GB each, and
saving them out of Podman and importing them takes 4 minutes alone and 12 beside the other test
sessions, which it slows twofold (docs/testing.md, "A loaded host"). So setup does
it (scripts/setup.d/55-node-images.sh runs ``python -m armnet_testbed.release_images``), after
the image builds and before any session starts; the fixture then finds every image imported,
and its own import, the same call, is the path for a run with pytest arguments.

Every name here is built from content: the shipped images' tags are content hashes, the
common tag joins them, the customer images are Podman layer-cached builds of fixed
files, and an import is skipped when the store's image came from the same Podman image id.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_testbed.containerd import PAUSE_IMAGE, import_into_store
from armnet_testbed.images import BASE_IMAGE, REPO_ROOT
from armnet_testbed.procs import progress
from armnet_testbed.shipped_images import AGENT, OPERATOR, RUNTIME, RUNTIME_LEROBOT, ensure_image

#: The prefix of the common tag; earlier runs' tags with it are superseded.
TAG_PREFIX = "it-"
EXAMPLE_JOB_IMAGE = "localhost/armnet-example-job:it"
BUS_LOOP_IMAGE = "localhost/armnet-bus-loop:it"
UNATTENDED_EVAL_IMAGE = "localhost/armnet-unattended-eval:it"
EXAMPLES = REPO_ROOT / "runtime" / "examples"


def repository(image: str) -> str:
    return image.rsplit(":", 1)[0]


@dataclass(frozen=True)
class ReleaseImages:
    """What the chart's install on the node runs: ``repository:tag`` references."""

    operator: str
    agent: str
    tag: str
    example_job: str
    bus_loop: str
    unattended_eval: str

    def all(self) -> tuple[str, ...]:
        return self.operator, self.agent, self.example_job, self.bus_loop, self.unattended_eval

    def is_superseded(self, name: str) -> bool:
        """An earlier run's common tag of the operator or agent repository (each holds a ~6 GB build)."""
        its_repository, _, tag = name.rpartition(":")
        return (its_repository in (repository(self.operator), repository(self.agent))
                and tag.startswith(TAG_PREFIX) and tag != self.tag)


def common_tag(client: Any, images: Sequence[str]) -> str:
    """One tag on every image (the chart has one ``image.tag``): the joined content hashes."""
    tag = TAG_PREFIX + "".join(image.rsplit(":", 1)[1][:6] for image in images)
    for image in images:
        client.images.get(image).tag(repository(image), tag)
    return tag


def build_on_runtime(client: Any, tag: str, runtime_image: str, context: Path) -> str:
    """``context``'s Containerfile built on ``runtime_image`` (its ``RUNTIME`` argument), as a customer would."""
    client.images.build(path=str(context), tag=tag, rm=True, dockerfile="Containerfile",
                        buildargs={"RUNTIME": runtime_image}, network_mode="none")
    return tag


def build_so101_job_image(client: Any, tag: str, script: Path, runtime_lerobot_image: str) -> str:
    """A customer's SO-101 job (``script`` as its main.py, with the examples' move helpers) as a customer
    would ship it: on the runtime's LeRobot variant."""
    context = Path(tempfile.mkdtemp(prefix="armnet-so101-job-"))
    try:
        shutil.copy(script, context / "main.py")
        shutil.copy(EXAMPLES / "_so101_moves.py", context / "_so101_moves.py")
        (context / "Containerfile").write_text("ARG RUNTIME\nFROM ${RUNTIME}\nCOPY main.py _so101_moves.py /app/\n")
        return build_on_runtime(client, tag, runtime_lerobot_image, context)
    finally:
        shutil.rmtree(context, ignore_errors=True)


def release_images(client: Any) -> ReleaseImages:
    """Build (or find) every image of the install and give the common tag to the operator and agent."""
    operator = ensure_image(OPERATOR, client=client)
    agent = ensure_image(AGENT, client=client)
    runtime = ensure_image(RUNTIME, client=client)
    runtime_lerobot = ensure_image(RUNTIME_LEROBOT, client=client)  # after the agent: their shared layer
    tag = common_tag(client, [operator, agent])
    example_job = build_on_runtime(client, EXAMPLE_JOB_IMAGE, runtime, REPO_ROOT / "images" / "example-job")
    bus_loop = build_so101_job_image(client, BUS_LOOP_IMAGE, EXAMPLES / "bus_loop.py", runtime_lerobot)
    unattended_eval = build_so101_job_image(client, UNATTENDED_EVAL_IMAGE,
                                            REPO_ROOT / "e2e" / "jobs" / "unattended_eval.py", runtime_lerobot)
    return ReleaseImages(operator=f"{repository(operator)}:{tag}", agent=f"{repository(agent)}:{tag}",
                         tag=tag, example_job=example_job, bus_loop=bus_loop, unattended_eval=unattended_eval)


def forget_superseded_tags(client: Any, images: ReleaseImages) -> None:
    """Untag earlier runs' common tags in Podman: each kept its ~6 GB build alive after a source change."""
    for image in client.images.list():
        for name in filter(images.is_superseded, image.tags):
            try:
                client.images.remove(name)
            except Exception as exc:  # noqa: BLE001 - in use by a container: the next run tries again
                progress(f"could not untag {name}: {exc}")


def main(argv: Sequence[str] | None = None) -> int:
    """Import the chart install's images (and the node's pause and base images) into the node's store."""
    import docker

    parser = argparse.ArgumentParser(prog="release-images", description=main.__doc__)
    parser.add_argument("--engine", required=True, help="Docker API of the Podman service")
    args = parser.parse_args(argv)
    client = docker.DockerClient(base_url=args.engine, timeout=3600)
    images = release_images(client)
    forget_superseded_tags(client, images)
    imported = import_into_store([PAUSE_IMAGE, BASE_IMAGE, *images.all()], forget=images.is_superseded)
    progress(f"the node's store holds {', '.join(images.all())} ({len(imported)} imported now)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
