"""The ``vp2`` command line. Thin: it parses arguments and calls library functions.

Each command's module parses its arguments, builds a config and calls library functions;
everything a command does, Python can do with the same functions.

One module per command: ``main_job`` (``vp2 main``), ``collect``, ``render``, ``tasks``, ``run``,
``train``, ``train_classifier``, ``metrics``, ``report``, ``ship_oracle``, ``study``, ``zoo``, ``diagnose``. Each has its
``NAME``, ``HELP`` and ``DESCRIPTION``, ``configure_parser(p)`` and ``run_from_args(args)``.

Run ``vp2 --help`` or ``vp2 <command> --help``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from types import ModuleType

#: The sub-commands in the order ``vp2 --help`` lists them: command name -> its module in
#: ``vp2.cli``. A command's module is imported only when that command runs (or when the full
#: parser is built: ``vp2 --help``, an unknown command), so ``vp2 train`` does not load the
#: simulators that ``vp2 collect`` needs.
COMMAND_MODULES: dict[str, str] = {
    "main": "main_job", "collect": "collect", "render": "render", "tasks": "tasks",
    "run": "run", "train": "train", "train-classifier": "train_classifier",
    "metrics": "metrics", "report": "report", "ship-oracle": "ship_oracle", "study": "study",
    "zoo": "zoo", "diagnose": "diagnose",
}


def command_module(name: str) -> ModuleType:
    """The module of command ``name`` (a key of :data:`COMMAND_MODULES`), imported."""
    return importlib.import_module(f"vp2.cli.{COMMAND_MODULES[name]}")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``vp2`` parser: every command's, or (``only``) that command's alone."""
    parser = argparse.ArgumentParser(prog="vp2", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in [only] if only is not None else COMMAND_MODULES:
        command = command_module(name)
        p = sub.add_parser(command.NAME, help=command.HELP, description=command.DESCRIPTION)
        command.configure_parser(p)
        p.set_defaults(fn=command.run_from_args)
    return parser


def _command_named(argv: Sequence[str]) -> str | None:
    """The command ``argv`` runs, if its first argument that is not ``-v`` names one."""
    rest = [a for a in argv if a not in ("-v", "--verbose")]
    return rest[0] if rest and rest[0] in COMMAND_MODULES else None


def main(argv: Sequence[str] | None = None) -> int:
    from vp2.data.storage import DatasetError

    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(_command_named(argv)).parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)
    try:
        return args.fn(args)
    except BrokenPipeError:
        # The reader of the output went away (``vp2 zoo list | head``): stop quietly, as a
        # shell tool does, with nothing left to flush at exit (SIGPIPE's exit status).
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (ValueError, FileExistsError, FileNotFoundError, DatasetError) as exc:
        print(f"vp2 {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        from vp2.benchmark.runner import ModelFailure

        if not isinstance(exc, ModelFailure):
            raise
        print(f"vp2 {args.command}: error: {exc}", file=sys.stderr)
        return 3



if __name__ == "__main__":
    sys.exit(main())
