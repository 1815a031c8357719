"""``armnet submit`` flags become a JobSpec, and a wrong flag is named in the error."""

from __future__ import annotations

import argparse

import pytest
from armnet_client.cli import submit
from armnet_client.errors import InvalidJob

pytestmark = pytest.mark.unit


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    submit.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_flags_map_onto_every_spec_field() -> None:
    spec = submit.spec_from_flags(parse(
        "--image", "ghcr.io/acme/pick:1.2", "--embodiment", "lerobot/so-101", "--task", "pick",
        "--args", '{"episodes": 3}', "--timeout", "600", "--secret", "HF_TOKEN=hf-token",
        "--secret", "WANDB=wb", "--detach"))

    assert spec.model_dump() == {
        "image": "ghcr.io/acme/pick:1.2", "embodiment": "lerobot/so-101", "task": "pick",
        "args": {"episodes": 3}, "timeout_seconds": 600,
        "secrets": {"HF_TOKEN": "hf-token", "WANDB": "wb"}, "detach": True, "username": None}


@pytest.mark.parametrize(("argv", "message"), [
    (("--image", "x:1"), "--image and --embodiment"),
    (("--image", "x:1", "--embodiment", "e", "--args", "[1]"), "--args must be a JSON object"),
    (("--image", "x:1", "--embodiment", "e", "--args", "{nope"), "--args must be a JSON object"),
    (("--image", "x:1", "--embodiment", "e", "--secret", "HF_TOKEN"), "use ENV=secret-name"),
    (("--image", "x:1", "--embodiment", "e", "--timeout", "0"), "timeout_seconds"),
])
def test_a_wrong_flag_is_named(argv: tuple[str, ...], message: str) -> None:
    with pytest.raises(InvalidJob, match=message):
        submit.spec_from_flags(parse(*argv))


def test_priority_and_preflight_are_spec_fields_beyond_the_sdks_model() -> None:
    extras = submit.spec_extras(parse("--image", "x:1", "--embodiment", "e", "--priority", "5", "--preflight", "60"))
    assert extras == {"priority": 5, "preflight": {"seconds": 60}}
    assert submit.spec_extras(parse("--image", "x:1", "--embodiment", "e")) == {}


@pytest.mark.parametrize("seconds", ["0", "3601", "-5"])
def test_a_preflight_out_of_the_crds_bounds_is_named(seconds: str) -> None:
    with pytest.raises(InvalidJob, match=f"--preflight takes 1 to 3600 seconds, not {int(seconds)}"):
        submit.spec_extras(parse("--image", "x:1", "--embodiment", "e", "--preflight", seconds))
