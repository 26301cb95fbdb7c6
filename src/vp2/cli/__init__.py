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
import logging
import os
import sys
from collections.abc import Sequence

from vp2.cli import (
    collect,
    diagnose,
    main_job,
    metrics,
    render,
    report,
    run,
    ship_oracle,
    study,
    tasks,
    train,
    train_classifier,
    zoo,
)

#: The sub-commands in the order ``vp2 --help`` lists them.
COMMANDS = (main_job, collect, render, tasks, run, train, train_classifier, metrics, report,
            ship_oracle, study, zoo, diagnose)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vp2", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        p = sub.add_parser(command.NAME, help=command.HELP, description=command.DESCRIPTION)
        command.configure_parser(p)
        p.set_defaults(fn=command.run_from_args)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from vp2.data.storage import DatasetError

    args = build_parser().parse_args(argv)
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
