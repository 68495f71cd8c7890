"""`foldcell router`: a Zenoh router where the cell's processes meet (required with --security)."""

from __future__ import annotations

import argparse
import dataclasses

from drivers.wire.security import ROUTER_ROLE
from drivers.wire.settings import open_session
from tools.common import (
    StopSignal,
    add_json_log,
    add_wire_arguments,
    announce,
    run_at_priority,
    wire_settings,
)


def cmd_router(args: argparse.Namespace) -> int:
    run_at_priority(args, "router", "router")
    settings = wire_settings(args, ROUTER_ROLE)
    if not args.connect:   # a router joins other routers only when told (not the cell's own endpoint)
        settings = dataclasses.replace(settings, connect=())
    session = open_session(settings)
    try:
        secured = f", secured by {settings.security}" if settings.security else ""
        announce(args, f"router serving {', '.join(settings.listen)}{secured}", listen=list(settings.listen),
                 secured=settings.security is not None)
        StopSignal().wait()
    finally:
        session.close()
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "router", help="a Zenoh router where the cell's processes meet",
        description="Serves the --listen endpoints (default config/cell.yaml's) as a Zenoh router and "
                    "forwards between the processes that connect to it. With --security DIR it is the "
                    "cell's checkpoint: TLS with client certificates from DIR's CA, and every client "
                    "held to its role's rights (config/security.yaml); start it before the others.")
    add_wire_arguments(p)
    add_json_log(p)
    p.set_defaults(func=cmd_router)
