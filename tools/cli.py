"""`foldcell`: one command, a subcommand per job. `foldcell SUBCOMMAND --help` explains each."""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import os
import sys
from collections.abc import Sequence

from tools.common import KNOWN_ERRORS, error_exit, setup_logging

# Each module has register(subparsers); order is the order of `foldcell --help`.
SUBCOMMAND_MODULES = (
    "tools.demo_cli",
    "tools.run_cli",
    "tools.controller_cli",
    "tools.camera_cli",
    "tools.perception_cli",
    "tools.dataset_cli",
    "tools.planning_cli",
    "tools.sim_cli",
    "tools.session_cli",
    "tools.topic_cli",
    "tools.replay_cli",
    "tools.monitor_cli",
    "tools.foxglove_cli",
    "tools.ros2_cli",
    "tools.router_cli",
    "tools.security_cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="foldcell",
        description="Garment-folding robot cell: the cell daemon, the DX100 controller emulator, the camera, "
                    "perception and planning tools, session logs (MCAP), replay and monitoring over Zenoh.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (repeatable)")
    parser.add_argument("--version", action="version", version=f"foldcell {_version()}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # a subcommand not part of this build
            raise
        module.register(subparsers)
    _everywhere(subparsers, f"foldcell {_version()}")
    return parser


def _version() -> str:
    try:
        return importlib.metadata.version("foldcell")
    except importlib.metadata.PackageNotFoundError:
        return "(not installed)"


def _everywhere(subparsers: argparse._SubParsersAction, version: str) -> None:
    """`-v` and `--version` after a subcommand too (`foldcell run -v`), as before it; nested
    subcommands included."""
    for sub in set(subparsers.choices.values()):
        sub.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                         help="more log output (repeatable)")
        sub.add_argument("--version", action="version", version=version)
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                _everywhere(action, version)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        setup_logging(args.verbose, getattr(args, "json_log", False))
        return int(args.func(args) or 0)
    except KNOWN_ERRORS as exc:
        return error_exit(str(exc))
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # the reader went away (`foldcell ... | head`): stop quietly, as a Unix filter does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
