"""``armnet completion bash|zsh``: the generated script completes subcommands, flags and flag values in real bash."""

from __future__ import annotations

import argparse
import functools
import shutil
import subprocess
from pathlib import Path

import pytest
from armnet_cli.completion import bash_script, describe, full_parser, zsh_script

pytestmark = pytest.mark.unit


@functools.lru_cache(maxsize=1)
def script() -> str:
    return bash_script(describe(full_parser()))


def complete(line: str, tmp_path: Path) -> list[str]:
    """What bash offers for ``line`` (the cursor at its end) with the generated script sourced."""
    words = line.split(" ")
    source = tmp_path / "armnet.bash"
    source.write_text(script())
    program = (
        f"source {source}\n"
        f"COMP_WORDS=({' '.join(repr(w) for w in words)})\n"
        f"COMP_CWORD={len(words) - 1}\n"
        "_armnet_complete\n"
        'printf "%s\\n" "${COMPREPLY[@]}"\n'
    )
    done = subprocess.run(["bash", "--norc", "--noprofile", "-c", program], capture_output=True, text=True,
                          cwd=tmp_path, timeout=30, check=True)
    return [w for w in done.stdout.splitlines() if w]


def test_subcommands_complete_after_armnet(tmp_path: Path) -> None:
    assert complete("armnet s", tmp_path) == ["sim", "submit"]
    assert {"logs", "get", "teleop", "completion", "agent", "operator"} <= set(complete("armnet ", tmp_path))


def test_a_subcommands_own_flags_complete(tmp_path: Path) -> None:
    assert complete("armnet submit --de", tmp_path) == ["--detach"]
    assert complete("armnet logs --t", tmp_path) == ["--tail"]


def test_flags_of_another_subcommand_are_not_offered(tmp_path: Path) -> None:
    assert "--detach" not in complete("armnet logs --", tmp_path)


def test_an_output_flag_completes_its_choices(tmp_path: Path) -> None:
    assert complete("armnet get -o ", tmp_path) == ["table", "wide", "json", "yaml", "name"]
    assert complete("armnet get --output j", tmp_path) == ["json"]


def test_a_file_flag_completes_file_names(tmp_path: Path) -> None:
    (tmp_path / "job.yaml").write_text("kind: RobotJob\n")
    assert complete("armnet submit -f jo", tmp_path) == ["job.yaml"]


def test_a_free_text_flag_value_gets_no_suggestions(tmp_path: Path) -> None:
    (tmp_path / "image-file").write_text("")
    assert complete("armnet submit --image im", tmp_path) == []


def test_the_first_positional_of_a_subcommand_with_choices_completes(tmp_path: Path) -> None:
    assert complete("armnet completion ", tmp_path) == ["bash", "zsh"]
    assert complete("armnet dev ", tmp_path) == ["up"]


def test_nothing_is_offered_after_the_job_name_was_given(tmp_path: Path) -> None:
    assert complete("armnet logs -f pick-1 ", tmp_path) == []


def test_describe_reads_flags_choices_and_positional_choices_from_argparse() -> None:
    parser = argparse.ArgumentParser()
    child = parser.add_subparsers().add_parser("thing")
    child.add_argument("mode", choices=("a", "b"))
    child.add_argument("-o", choices=("x", "y"))
    child.add_argument("--path", type=Path)
    child.add_argument("--flag", action="store_true")
    (command,) = describe(parser)
    assert command.name == "thing" and command.first == ("a", "b")
    assert command.values == {"-o": ("x", "y"), "--path": ("@file",)}
    assert "--flag" in command.flags and "--flag" not in command.values


def zsh_complete(line: str, tmp_path: Path) -> set[str]:
    """What the function offers in zsh, called as bashcompinit's ``compgen -F`` calls it (sh emulation).

    zsh's ``compgen -W`` leaves matching the typed prefix to zsh itself, so this is a set of candidates.
    """
    words = line.split(" ")
    source = tmp_path / "_armnet"
    source.write_text(zsh_script(describe(full_parser())))
    program = (f"source {source}\n"
               f"emulate -L sh\nsetopt kshglob noshglob braceexpand\n"
               f"COMP_WORDS=({' '.join(repr(w) for w in words)})\nCOMP_CWORD={len(words) - 1}\n"
               "_armnet_complete\nprintf '%s\\n' \"${COMPREPLY[@]}\"\n")
    done = subprocess.run(["zsh", "-f", "-c", program], capture_output=True, text=True, cwd=tmp_path,
                          timeout=30, check=True)
    return {w for w in done.stdout.splitlines() if w}


@pytest.mark.skipif(shutil.which("zsh") is None, reason="zsh is not installed here")
def test_in_zsh_the_same_function_offers_subcommands_flags_and_choices(tmp_path: Path) -> None:
    assert {"submit", "logs", "completion"} <= zsh_complete("armnet ", tmp_path)
    assert "--detach" in zsh_complete("armnet submit --de", tmp_path)
    assert zsh_complete("armnet get -o ", tmp_path) == {"table", "wide", "json", "yaml", "name"}
    assert zsh_complete("armnet completion ", tmp_path) == {"bash", "zsh"}


def test_the_zsh_script_is_the_bash_function_through_bashcompinit() -> None:
    text = zsh_script(describe(full_parser()))
    assert "bashcompinit" in text and "complete -F _armnet_complete armnet" in text
