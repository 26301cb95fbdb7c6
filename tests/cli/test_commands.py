"""The command table of ``vp2``: names, and that a command loads only its own module."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vp2 import cli


def test_every_command_module_is_named_as_its_command():
    names = [cli.command_module(name).NAME for name in cli.COMMAND_MODULES]
    assert names == list(cli.COMMAND_MODULES)
    assert len(names) == 13
    choices = cli.build_parser()._subparsers._group_actions[0].choices  # noqa: SLF001
    assert list(choices) == list(cli.COMMAND_MODULES)


@pytest.mark.parametrize(("argv", "command"), [
    (["train", "--steps", "3"], "train"), (["-v", "zoo", "list"], "zoo"),
    (["--help"], None), (["trian"], None), ([], None)])
def test_the_command_is_read_from_the_first_argument(argv, command):
    assert cli._command_named(argv) == command  # noqa: SLF001


def test_a_training_command_does_not_load_the_simulators():
    code = ("import sys\nfrom vp2 import cli\ntry:\n    cli.main(['train', '--help'])\n"
            "except SystemExit:\n    pass\n"
            "print(sorted(m for m in ('robosuite', 'mujoco', 'numba', 'robodesk') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "usage: vp2 train" in out
    assert out.strip().splitlines()[-1] == "[]"


def test_an_unknown_command_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["trian"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'trian'" in err and "train-classifier" in err and "diagnose" in err
