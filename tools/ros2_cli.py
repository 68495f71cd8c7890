"""`foldcell ros2`: show a live cell to ROS 2 nodes running rmw_zenoh_cpp (README "ROS 2 users")."""

from __future__ import annotations

import argparse
import os
from typing import Any

from drivers.ros2.config import ENV_DOMAIN, check_domain_id, load_ros2_config
from drivers.ros2.names import RosNameError
from drivers.ros2.types import ServiceTypeError
from drivers.wire.settings import check_endpoint
from drivers.wire.transport import Wire
from tools.common import (
    ALL_CELLS,
    StopSignal,
    add_json_log,
    add_wire_arguments,
    announce,
    error_exit,
    wire_settings,
)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "ros2",
        help="bridge a live cell to ROS 2 nodes on rmw_zenoh (ros2 topic list/echo/hz, ros2 service call)",
        description="Show a live cell to ROS 2 (Jazzy or later) nodes running rmw_zenoh_cpp: every key the "
        "cell publishes becomes the topic /foldcell/<cell>/<key> (the bytes are already ROS 2 CDR) and "
        "cell/command the service /foldcell/<cell>/cell/command (foldcell_msgs/srv/CellCommand), with "
        "rmw_zenoh's key expressions, type hashes and graph tokens. The bridge joins the cell as every "
        "foldcell process does (--connect, ...) and the ROS 2 side at its router, rmw_zenohd "
        "(--ros-connect). Runs until Ctrl-C.",
    )
    p.add_argument("--ros-connect", metavar="ENDPOINT", action="append",
                   help="the ROS 2 side's Zenoh router, repeatable (default from config/ros2.yaml: "
                   "tcp/127.0.0.1:7447, where rmw_zenohd listens)")
    p.add_argument("--domain-id", metavar="N",
                   help=f"ROS domain id (default ${ENV_DOMAIN}, else config/ros2.yaml's, 0)")
    p.add_argument("--print", action="store_true", dest="print_only",
                   help="print each topic and service ROS 2 sees (name, type, hash, Zenoh key) and exit")
    add_wire_arguments(p)
    add_json_log(p)
    p.set_defaults(func=cmd_ros2)


def cmd_ros2(args: argparse.Namespace) -> int:
    config = load_ros2_config()
    if args.cell == ALL_CELLS:
        return error_exit("--cell: the bridge shows one cell; run one bridge per cell")
    if args.domain_id is not None:
        domain = check_domain_id(args.domain_id, "--domain-id")
    elif os.environ.get(ENV_DOMAIN):
        domain = check_domain_id(os.environ[ENV_DOMAIN], ENV_DOMAIN)
    else:
        domain = config.domain_id
    connect = tuple(check_endpoint(e, "--ros-connect") for e in args.ros_connect or config.connect)
    settings = wire_settings(args, "operator")   # reads every key, calls cell/command
    if args.print_only:
        return _print(settings.cell_id, config, domain)
    from drivers.ros2.bridge import Ros2Bridge

    stop = StopSignal()
    with Wire(settings, f"cli-ros2-{os.getpid()}") as wire:
        try:
            bridge = Ros2Bridge(wire, config, domain, connect)
        except (RosNameError, ServiceTypeError) as exc:
            return error_exit(str(exc))
        try:
            announce(args, f"bridging foldcell/{settings.cell_id} to ROS 2 domain {domain} at "
                     f"{', '.join(connect)} (Ctrl-C to stop)", cell=settings.cell_id, domain=domain,
                     connect=list(connect))
            stop.wait()
        finally:
            bridge.close()
    return 0


def _print(cell: str, config: Any, domain: int) -> int:
    from drivers.ros2 import names, types
    from drivers.wire.registry import KEYS

    try:
        names.check_token(cell, "--cell")
    except RosNameError as exc:
        return error_exit(str(exc))
    for spec in KEYS:
        if spec.kind == "pub" and "*" not in spec.pattern:
            name = names.ros_name(config.namespace, cell, spec.pattern)
            key = names.data_key(domain, name, spec.type_name, types.message_hash(spec.type_name))
            print(f"topic   {name}  {spec.type_name}\n        {key}")
    for relative_key, srv_type in config.services.items():
        name = names.ros_name(config.namespace, cell, relative_key)
        key = names.data_key(domain, name, srv_type, types.service_hash(srv_type))
        print(f"service {name}  {srv_type}\n        {key}")
    return 0
