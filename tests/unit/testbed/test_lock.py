"""The committed lock (lock/): every environment holds one set of versions, and it is current.

What these read is the committed text; scripts/lock.sh (uv, the registry) writes it.
"""

from __future__ import annotations

import pytest
from armnet_testbed.lockfile import (
    INPUTS_DIGEST,
    LOCK_DIR,
    OVERRIDES,
    inputs_digest,
    lock_file,
    normalize,
    overridden,
    pins,
    unexcused,
)

pytestmark = pytest.mark.unit

IMAGE_LOCKS = ("runtime", "platform", "lerobot")


def _pins(name: str) -> dict[str, str]:
    return pins(lock_file(name).read_text())


def test_the_lock_was_compiled_from_the_current_dependency_declarations() -> None:
    recorded = INPUTS_DIGEST.read_text().strip()

    assert recorded == inputs_digest(), (
        "a pyproject dependency, lock/*.in or lock/overrides.txt changed since the lock was "
        "compiled: run scripts/lock.sh and commit lock/")


@pytest.mark.parametrize("image", IMAGE_LOCKS)
def test_each_image_lock_holds_the_dev_locks_version_of_every_package(image: str) -> None:
    dev = _pins("dev")

    differing = {name: (version, dev.get(name)) for name, version in _pins(image).items()
                 if dev.get(name) != version}

    assert differing == {}


def test_the_image_locks_nest_runtime_in_platform_in_lerobot() -> None:
    runtime, platform, lerobot = (set(_pins(name)) for name in IMAGE_LOCKS)

    assert runtime - platform == set()
    assert platform - lerobot == set()
    assert {"lerobot", "torch", "torchvision"} <= lerobot - platform


def test_our_own_distributions_are_left_out_of_every_lock() -> None:
    for name in ("dev", *IMAGE_LOCKS):
        assert {"armnet", "armnet-runtime"} & set(_pins(name)) == set(), name


def test_every_lock_line_carries_hashes() -> None:
    for path in sorted(LOCK_DIR.glob("*.txt")):
        if path == OVERRIDES:
            continue
        blocks = [b for b in path.read_text().split("\n") if b and not b.startswith((" ", "#"))]
        unhashed = [b for b in blocks if not b.endswith("\\")]
        assert unhashed == [], path.name


def test_every_override_has_its_reason_just_above_it_and_is_what_the_lock_holds() -> None:
    lines = OVERRIDES.read_text().splitlines()
    dev = _pins("dev")

    for i, line in enumerate(lines):
        if not line.strip() or line.startswith("#"):
            continue
        assert lines[i - 1].startswith("#"), f"overrides.txt: {line!r} has no reason above it"
        name, version = line.split("==")
        assert dev[normalize(name)] == version.strip()


def test_a_conflict_on_an_overridden_package_is_excused_and_nothing_else_is() -> None:
    output = (
        "lerobot 0.4.4 has requirement torch<2.11.0,>=2.2.1, but you have torch 2.13.0.\n"
        "lerobot 0.4.4 has requirement torchvision<0.26.0,>=0.21.0, but you have torchvision 0.28.0.\n"
        "lerobot 0.4.4 has requirement av<16.0.0,>=15.0.0, but you have av 18.1.0.\n"
        "lerobot 0.4.4 requires gymnasium, which is not installed.\n"
        "torch 2.13.0 requires torch, which is not installed.\n")

    assert unexcused(output, frozenset({"torch", "torchvision"})) == [
        "lerobot 0.4.4 has requirement av<16.0.0,>=15.0.0, but you have av 18.1.0.",
        "lerobot 0.4.4 requires gymnasium, which is not installed.",
        "torch 2.13.0 requires torch, which is not installed.",
    ]


def test_a_clean_pip_check_leaves_nothing() -> None:
    assert unexcused("No broken requirements found.\n", frozenset()) == []


def test_names_compare_as_the_registry_does() -> None:
    output = "x 1 has requirement Typing_Extensions>=9, but you have typing-extensions 4.\n"

    assert unexcused(output, overridden("typing.extensions==4\n")) == []
