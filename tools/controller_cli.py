"""`foldcell controller ...`: run the DX100 emulator and drive it by hand."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

from tqdm import tqdm

from drivers.common.configfile import ConfigError
from drivers.controller import codec
from drivers.controller.codes import Command
from drivers.controller.errors import ControllerError
from drivers.controller.interface import MotionHandle, MotionStatus
from drivers.controller.trajfile import load_trajectory
from drivers.emulator.commands import EmulatorCommand
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.settings import WireSettings, on_this_machine
from drivers.wire.transport import Wire
from tools.common import (
    StopSignal,
    UsageError,
    add_json_log,
    add_wire_arguments,
    announce,
    check_seconds,
    error_exit,
    path_argument,
    print_json,
    run_at_priority,
    wire_settings,
)

log = logging.getLogger(__name__)

FAULTS = {  # CLI name -> (on, off, number of values when on)
    "drop-slave-link": (EmulatorCommand.FAULT_DROP_SLAVE_LINK_ON, EmulatorCommand.FAULT_DROP_SLAVE_LINK_OFF,
                        0),
    "freeze-feedback": (EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON, EmulatorCommand.FAULT_FREEZE_FEEDBACK_OFF,
                        0),
    "alarm": (EmulatorCommand.FAULT_ALARM_ON, EmulatorCommand.FAULT_ALARM_OFF, 0),
    "reply-latency": (EmulatorCommand.FAULT_REPLY_LATENCY_ON, EmulatorCommand.FAULT_REPLY_LATENCY_OFF, 2),
    "slow-loop": (EmulatorCommand.FAULT_SLOW_LOOP_ON, EmulatorCommand.FAULT_SLOW_LOOP_OFF, 1),
}

DIALECTS = ("upstream", "clopema")
MOTOROS_START_WAIT_S = 5.0   # how long a --motoros command tries again a server that refuses connections
# with --motoros: what works, and why the rest is refused (MotoROS 1 commands: shared/facts, section 5)
MOTOROS_COMMANDS = frozenset({"status", "servo", "estop", "stop", "watch", "home", "send", "grip"})
MOTOROS_REFUSED = {
    "reset": "MotoROS has no e-stop reset (the pendant's); `servo on` resets the alarms",
    "hold": "MotoROS has no hold; use `stop` (STOP_MOTION)",
    "resume": "MotoROS has no hold to resume",
    "jog": "MotoROS moves by streamed points only; use `send` or `home`",
    "fault": "fault injection is the emulator's, over Zenoh only",
}


def register(subparsers: Any) -> None:
    ctl = subparsers.add_parser(
        "controller", help="the DX100 master/slave emulator and hand commands to it",
        description="Run the DX100/MotoROS-style controller emulator over Zenoh, or drive a running one. "
                    "Motion commands take the control lease for their duration and fail if another "
                    "process holds it.")
    group = ctl.add_subparsers(dest="controller_command", metavar="COMMAND", required=True)

    def sub(name: str, help_text: str, func: Any, timeout: bool = False) -> argparse.ArgumentParser:
        p = group.add_parser(name, help=help_text, description=help_text)
        if timeout:
            p.add_argument("--timeout", type=float, default=60.0, metavar="S",
                           help="wall seconds to wait for the motion to finish (default 60)")
        p.add_argument("--json", action="store_true", help="one JSON document on stdout")
        motoros = p.add_argument_group("MotoROS (a real DX100, or `serve --motoros`) instead of Zenoh")
        motoros.add_argument("--motoros", metavar="HOST[:PORT]",
                             help="talk MotoROS 1 over TCP: motion port PORT, state port PORT+1 (default "
                                  "port from config/motoros.yaml, 50240); with --security over TLS, as "
                                  "the operator" +
                                  ("" if name in MOTOROS_COMMANDS else "; refused: " + MOTOROS_REFUSED[name]))
        motoros.add_argument("--motoros-dialect", choices=DIALECTS,
                             help="upstream MotoROS 1 or CloPeMa's 13-slot fork "
                                  "(default from config/motoros.yaml)")
        add_wire_arguments(p)
        p.set_defaults(func=func)
        return p

    _register_serve(group)

    sub("status", "print the controller's status", cmd_status)
    p = sub("servo", "switch the servos (and MotoROS trajectory mode) on or off; with --motoros: on = "
                     "START_SERVOS + START_TRAJ_MODE (the fork: START_TRAJ_MODE), off = STOP_SERVOS",
            cmd_servo)
    p.add_argument("state", choices=("on", "off"))
    sub("estop", "emergency stop: every axis stops on the next tick; needs reset and servo on. With "
                 "--motoros, which has no e-stop message: STOP_MOTION + STOP_SERVOS (the fork: STOP_MOTION + "
                 "STOP_TRAJ_MODE), no safety function; `servo on` moves again", cmd_simple)
    sub("reset", "reset the e-stop and the alarms (servos stay off)", cmd_reset)
    sub("hold", "hold: pause the motion smoothly", cmd_simple)
    sub("resume", "resume a held motion", cmd_simple)
    sub("stop", "decelerate within the limits and drop the queue", cmd_simple)
    sub("home", "move every joint to the home position of config/robot/joints.yaml", cmd_home, timeout=True)
    p = sub("jog", "move one joint by DELTA rad", cmd_jog, timeout=True)
    p.add_argument("joint", help="joint name, e.g. r1_joint_s")
    p.add_argument("delta", type=float, help="rad (negative numbers after --)")
    p = sub("grip", "open or close an arm's gripper", cmd_grip)
    p.add_argument("arm", help="r1 or r2")
    p.add_argument("state", choices=("open", "close"))
    p = sub("send", "submit a trajectory file and wait for it to finish", cmd_send, timeout=True)
    p.add_argument("trajectory", type=path_argument,
                   help="trajectory YAML (see drivers/controller/trajfile.py)")
    p = sub("watch", "print status changes and joint positions until Ctrl-C", cmd_watch)
    p.add_argument("--rate", type=float, default=2.0, metavar="HZ", help="joint lines per second (default 2)")
    p = sub("fault", "switch an injected fault on or off (tests and demos; takes the control lease for the "
                     "command, refused while another process holds it)", cmd_fault)
    p.add_argument("name", choices=sorted(FAULTS))
    p.add_argument("state", choices=("on", "off"))
    p.add_argument("values", type=float, nargs="*",
                   help="reply-latency: LATENCY_S JITTER_S; slow-loop: FACTOR")


# ---------------------------------------------------------------- serve
def cmd_serve(args: argparse.Namespace) -> int:
    from drivers.common.scheduling import load_priorities, set_thread_fifo
    from drivers.controller.config import load_controller_config
    from drivers.controller.interface import PROCESS_NAMES
    from drivers.emulator.master import MasterNode
    from drivers.emulator.node import SECURITY_ROLES, ControllerNode, load_server_config

    if args.time_scale is not None and not 0 < args.time_scale < math.inf:
        return error_exit(f"--time-scale: must be a finite number > 0, got {args.time_scale}")
    if args.motoros and args.role != "both":
        return error_exit(f"--motoros: MotoROS is served by the role both only, got --role {args.role}")
    config = load_controller_config(args.controller_config)
    server = load_server_config(args.controller_config)
    robot = default_robot_config()
    stop = StopSignal()
    settings = wire_settings(args, SECURITY_ROLES[args.role])
    if args.motoros_plain and not args.motoros:
        return error_exit("--motoros-plain: only with --motoros")
    run_at_priority(args, "controller", PROCESS_NAMES[args.role])
    wire = Wire(settings, PROCESS_NAMES[args.role], announce=False)
    try:
        node = MasterNode(wire, robot, config, server, args.time_scale) if args.role == "master" else \
            ControllerNode(wire, args.role, robot, config, server, args.time_scale)
    except Exception:
        wire.close()
        raise
    motoros = None
    if args.motoros:
        try:
            motoros = start_motoros(args, node, settings)
        except (OSError, ValueError) as exc:
            node.close()
            return error_exit(f"--motoros {args.motoros}: {exc}")
    wire.announce()  # alive only once its keys are served
    announce(args, f"controller {args.role} serving cell {wire.cell_id} (time scale {node.time_scale:g})",
             role=args.role, cell=wire.cell_id, time_scale=node.time_scale)
    sys.setswitchinterval(server.gil_switch)
    set_thread_fifo(load_priorities(args.config).controller_loop_fifo, "the controller loop")
    try:
        node.run(stop)
    finally:
        if motoros is not None:
            motoros.close()
        node.close()
    return 0

def _register_serve(group: Any) -> None:
    p = group.add_parser("serve", help="run the emulator (master, slave or both) until SIGINT/SIGTERM",
                         description="Run the DX100 emulator: `both` drives every group in one process; "
                                     "`master` and `slave` are the two controllers as separate processes.")
    p.add_argument("--role", choices=("master", "slave", "both"), default="both",
                   help="which controller this process is (default both)")
    p.add_argument("--time-scale", type=float, metavar="K",
                   help="robot time runs K times faster than wall time (default from config/controller.yaml)")
    p.add_argument("--controller-config", metavar="FILE",
                   help="controller config (default config/controller.yaml)")
    p.add_argument("--motoros", metavar="HOST[:PORT]",
                   help="also serve MotoROS clients: motion port PORT, state port PORT+1, IO port PORT+2 "
                        "(default port from config/motoros.yaml, 50240); role both only. With --security "
                        "every port is TLS and admits only certificates of roles that may command the "
                        "controller (config/security.yaml)")
    p.add_argument("--motoros-plain", action="store_true",
                   help="with --security: serve MotoROS as a real DX100 does, plain TCP that anyone who "
                        "reaches it may command, on 127.0.0.1 only whatever HOST says (for a local client "
                        "that cannot speak TLS)")
    p.add_argument("--motoros-dialect", choices=DIALECTS,
                   help="MotoROS 1 on a DX100 (10 slots per group) or CloPeMa's 13-slot fork "
                        "(default from config/motoros.yaml)")
    add_wire_arguments(p)
    add_json_log(p)
    p.set_defaults(func=cmd_serve)


def start_motoros(args: argparse.Namespace, node: Any, settings: WireSettings) -> Any:
    """A MotoROS server over the node's core, stepped by the node's loop (one robot for both sides):
    under --security over TLS with the process's certificate, or, --motoros-plain, on loopback only."""
    address, dialect, plain = args.motoros, args.motoros_dialect, args.motoros_plain
    from drivers.emulator.motoros_server import MotorosServer, ServerTls
    from drivers.motoros.config import load_motoros_config
    from drivers.wire.tls import roles_calling, server_context

    config = load_motoros_config()
    host, port = motoros_address(address, config.port)
    asked = host or "0.0.0.0"
    plain_under_security = settings.security is not None and plain
    tls = None
    if settings.security is not None and not plain:
        tls = ServerTls(server_context(settings.security, settings.role, settings.security_source),
                        roles_calling("controller/command"))
    server = MotorosServer(node.core, node.lock, config, "127.0.0.1" if plain_under_security else asked, port,
                           dialect, heard=node.heard_from, tls=tls)
    server.start()
    if plain_under_security:
        log.warning("MotoROS on plain TCP under --security (--motoros-plain): unauthenticated, whoever "
                    "reaches 127.0.0.1:%d may move the robot; bound to 127.0.0.1 only%s", server.ports[0],
                    "" if asked == "127.0.0.1" else f" (not {asked})")
    elif settings.security is None and not on_this_machine(f"tcp/{asked}:{server.ports[0]}"):
        log.warning("MotoROS on %s: this process is open (no --security) and its MotoROS ports listen beyond "
                    "this machine: anyone who can reach them can move the robot. Serve on 127.0.0.1, or "
                    "secure the cell (README: A locked-down cell)", asked)
    node.tick_listeners.append(server)
    ports = ", ".join(f"{kind} port {port}" for kind, port in zip(server.kinds, server.ports, strict=True))
    over = f" over TLS for {', '.join(sorted(tls.roles))}" if tls else ""
    announce(args, f"MotoROS ({server.dialect.name}) on {server.host}{over}: {ports}",
             dialect=server.dialect.name, host=server.host, ports=list(server.ports), tls=tls is not None)
    return server


def motoros_address(address: str, default_port: int) -> tuple[str, int]:
    """HOST[:PORT] -> (host, port); '' host for ':PORT'."""
    host, _, port = address.rpartition(":") if ":" in address else (address, "", "")
    if port and not port.isdigit():
        raise ValueError(f"PORT must be a number, got {port!r}")
    return host, int(port) if port else default_port


# ---------------------------------------------------------------- clients
class _Session:
    """A connected controller client for one CLI command: `ZenohController`, or `MotorosController`
    with --motoros."""

    def __init__(self, args: argparse.Namespace):
        self.wire: Wire | None = None
        if getattr(args, "motoros", None):
            from drivers.controller.motoros_client import MotorosController
            from drivers.motoros.config import load_motoros_config
            from drivers.wire.tls import client_context

            config = load_motoros_config()
            try:
                host, port = motoros_address(args.motoros, config.port)
            except ValueError as exc:
                raise UsageError(f"--motoros {args.motoros}: {exc}") from None
            settings = wire_settings(args, "operator")
            tls = (client_context(settings.security, "operator", settings.security_source)
                   if settings.security else None)
            self.ctl: Any = MotorosController(host or "127.0.0.1", port, args.motoros_dialect,
                                              motoros_config=config, tls=tls)
            return
        from drivers.controller.zenoh_client import ZenohController

        # `cli-`: a tool never takes (or looks like) the name of a process the cell depends on
        name = f"cli-controller-{time.monotonic_ns() % 10**9}"
        self.wire = Wire(wire_settings(args, "operator"), name)
        self.ctl = ZenohController(self.wire)

    def __enter__(self) -> Any:
        # a MotoROS server refuses connections while it starts (`serve --motoros ... &` and a command right
        # after): tried again for a few seconds, as a Zenoh command waits for the controller's first status
        deadline = time.monotonic() + MOTOROS_START_WAIT_S
        try:
            while True:
                try:
                    self.ctl.connect()
                    break
                except ControllerError as exc:
                    if not isinstance(exc.__cause__, ConnectionRefusedError) or time.monotonic() > deadline:
                        raise
                    time.sleep(0.2)
        except BaseException:
            if self.wire is not None:
                self.wire.close()
            raise
        return self.ctl

    def __exit__(self, *exc: object) -> None:
        try:
            self.ctl.disconnect()
        finally:
            if self.wire is not None:
                self.wire.close()


def _open(args: argparse.Namespace) -> _Session | str:
    """The command's session, or why there is none (a subcommand MotoROS cannot carry); a bad flag
    raises, naming itself."""
    name = args.controller_command
    if getattr(args, "motoros", None) and name not in MOTOROS_COMMANDS:
        return f"controller {name} --motoros: {MOTOROS_REFUSED[name]}"
    return _Session(args)


def _run(args: argparse.Namespace, action: Any) -> int:
    """Connect, run `action(ctl) -> dict`, print; controller errors -> exit 1 with the code."""
    check_seconds("--timeout", getattr(args, "timeout", None))
    session = _open(args)
    if isinstance(session, str):
        return error_exit(session)
    try:
        with session as ctl:
            result = action(ctl) or {}
    except ControllerError as exc:
        if getattr(args, "json", False):
            print_json({"ok": False, "error": exc.text, "result": exc.result, "subcode": exc.subcode,
                        "point": exc.point, "joint": exc.joint})
        return error_exit(str(exc), 1)
    except (ConfigError, FileNotFoundError) as exc:
        return error_exit(str(exc), 2)
    if getattr(args, "json", False):
        print_json({"ok": True, **result})
    elif result.get("message"):
        print(result["message"])
    return 0 if result.get("ok", True) else 1


def _with_lease(ctl: Any, body: Any) -> Any:
    ctl.acquire_lease()
    try:
        return body()
    finally:
        ctl.release_lease()


def _status_dict(ctl: Any) -> dict:
    if hasattr(ctl, "status_message"):
        msg = ctl.status_message()
    else:  # MotoROS: the same message built from the status the state port gives
        robot = ctl.robot_config
        status = ctl.status()
        msg = codec.status_msg(status, round(status.stamp * 1e9), status.time_scale,
                               group_joints={g.name: g.joints for g in robot.groups})
    data = messages.to_dict(msg)
    data["stamp"] = messages.stamp_to_ns(msg.header.stamp) * 1e-9
    data.pop("header", None)
    return data


def _status_line(data: dict) -> str:
    flags = [name for name in ("drives_powered", "e_stopped", "in_error", "in_motion", "motion_possible",
                               "held", "trajectory_mode") if data.get(name) == 1]
    alarm = f" alarm {data['error_code']}: {data['alarm_text']}" if data.get("error_code") else ""
    groups = " ".join(f"{g['name']}({g['controller']}{'' if g['link_ok'] == 1 else ', link lost'})"
                      for g in data.get("groups", []))
    lease = data.get("lease_holder") or "-"
    faults = ",".join(data.get("faults") or []) or "-"
    return (f"t={data['stamp']:.3f} [{' '.join(flags) or 'idle'}]{alarm} queue {data['queue_count']} "
            f"lease {lease} faults {faults} groups {groups}")


def cmd_status(args: argparse.Namespace) -> int:
    def action(ctl: Any) -> dict:
        data = _status_dict(ctl)
        fb = ctl.joint_state()
        data["joints"] = dict(zip(fb.joint_names, fb.positions.tolist(), strict=True))
        return {"status": data, "message": _status_line(data)}
    return _run(args, action)


def cmd_servo(args: argparse.Namespace) -> int:
    codes = [Command.START_TRAJ_MODE] if args.state == "on" else [Command.STOP_SERVOS]
    if args.motoros and args.state == "on" and _dialect(args) == "upstream":
        # an explicit START_SERVOS: the emulator's START_TRAJ_MODE never switches servos on after an e-stop
        codes.insert(0, Command.START_SERVOS)
    if args.motoros and args.state == "off" and _dialect(args) == "clopema":
        return error_exit("controller servo off --motoros: CloPeMa's MotoROS has no STOP_SERVOS")
    return _run(args, lambda ctl: _with_lease(
        ctl, lambda: ([ctl.command(code) for code in codes], {"message": f"servo {args.state}"})[1]))


def _dialect(args: argparse.Namespace) -> str:
    if args.motoros_dialect:
        return str(args.motoros_dialect)
    from drivers.motoros.config import load_motoros_config

    return load_motoros_config().dialect


_SIMPLE = {"estop": Command.ESTOP, "hold": Command.HOLD, "resume": Command.RESUME,
           "stop": Command.STOP_MOTION}


def cmd_simple(args: argparse.Namespace) -> int:
    code = _SIMPLE[args.controller_command]
    if code == Command.ESTOP and args.motoros:
        # simple message has no e-stop: stop the motion, then the servos (the fork: end trajectory mode)
        off = Command.STOP_TRAJ_MODE if _dialect(args) == "clopema" else Command.STOP_SERVOS
        message = f"stopped: STOP_MOTION + {off.name} (MotoROS has no e-stop; this is no safety stop)"
        return _run(args, lambda ctl: (ctl.command(Command.STOP_MOTION), ctl.command(off),
                                       {"message": message})[2])
    if code == Command.ESTOP:  # works from any session, no lease
        return _run(args, lambda ctl: (ctl.command(code), {"message": "e-stop engaged"})[1])
    return _run(args, lambda ctl: _with_lease(ctl, lambda: (ctl.command(code),
                                                            {"message": args.controller_command})[1]))


def cmd_reset(args: argparse.Namespace) -> int:
    def body(ctl: Any) -> dict:
        ctl.command(Command.ESTOP_RESET)
        ctl.command(Command.RESET_ALARM)
        return {"message": "e-stop and alarms reset (switch servos on to move)"}
    return _run(args, lambda ctl: _with_lease(ctl, lambda: body(ctl)))


def _follow(handle: MotionHandle, ctl: Any, timeout: float, label: str) -> dict:
    """Wait for a motion with a progress bar (robot seconds) on stderr."""
    start = time.monotonic()
    bar = tqdm(desc=label, unit="s", total=None, file=sys.stderr, leave=False,
               bar_format="{desc}: {elapsed} {postfix}")
    try:
        while True:
            result = handle.wait(0.2)
            st = ctl.status()
            bar.set_postfix_str(f"robot t={st.stamp:.2f}")
            bar.update(0)
            if result != MotionStatus.RUNNING or time.monotonic() - start > timeout:
                break
    finally:
        bar.close()
    ok = result == MotionStatus.SUCCEEDED
    fb = ctl.joint_state()
    return {"ok": ok, "motion": result.value, "message": f"{label}: {result.value}",
            "joints": dict(zip(fb.joint_names, fb.positions.tolist(), strict=True))}


def cmd_home(args: argparse.Namespace) -> int:
    robot = default_robot_config()
    return _run(args, lambda ctl: _with_lease(
        ctl, lambda: _follow(ctl.move_to(robot.home), ctl, args.timeout, "home")))


def _one_of(field: str, value: str, names: Sequence[str]) -> None:
    """Checked before connecting: a typo is bad input, not a controller that does not answer."""
    if value not in names:
        raise UsageError(f"{field}: must be one of {', '.join(names)}, got {value!r}")


def _finite(field: str, values: Sequence[float]) -> None:
    """NaN and infinity, refused before connecting rather than sent to the controller."""
    if not all(map(math.isfinite, values)):
        given = ' '.join(f'{v:g}' for v in values)
        raise UsageError(f"{field}: must be finite (not nan or inf), got {given}")


def cmd_jog(args: argparse.Namespace) -> int:
    _one_of("joint", args.joint, default_robot_config().joint_names)
    _finite("delta", [args.delta])
    return _run(args, lambda ctl: _with_lease(
        ctl, lambda: _follow(ctl.jog(args.joint, args.delta), ctl, args.timeout, f"jog {args.joint}")))


def cmd_grip(args: argparse.Namespace) -> int:
    _one_of("arm", args.arm, [arm.name for arm in default_robot_config().arms])
    return _run(args, lambda ctl: _with_lease(
        ctl, lambda: (ctl.grip(args.arm, args.state == "close"), {"message": f"{args.arm} {args.state}"})[1]))


def cmd_send(args: argparse.Namespace) -> int:
    traj = load_trajectory(args.trajectory, default_robot_config())  # file errors before connecting
    return _run(args, lambda ctl: _with_lease(
        ctl, lambda: _follow(ctl.execute(traj), ctl, args.timeout, "trajectory")))


def cmd_fault(args: argparse.Namespace) -> int:
    on, off, nvalues = FAULTS[args.name]
    values = tuple(args.values) if args.state == "on" else ()
    _finite("values", values)
    if args.state == "on" and len(values) != nvalues:
        return error_exit(f"fault {args.name} on takes {nvalues} value(s), got {len(values)}")
    if args.state == "off" and args.values:
        return error_exit(f"fault {args.name} off takes no values")
    code = on if args.state == "on" else off
    message = f"fault {args.name} {args.state}"
    return _run(args, lambda ctl: _with_lease(ctl, lambda: (ctl.command(code, values=values),
                                                          {"message": message})[1]))


def cmd_watch(args: argparse.Namespace) -> int:
    if not args.rate > 0:
        return error_exit(f"--rate must be > 0, got {args.rate}")
    stop = StopSignal()

    def action(ctl: Any) -> dict:
        last = None
        next_joints = 0.0
        while not stop.is_set():
            data = _status_dict(ctl)
            line = _status_line(data)
            key = line.split(" ", 1)[1]
            if key != last:
                print(json.dumps(data) if args.json else line, flush=True)
                last = key
            now = time.monotonic()
            if now >= next_joints:
                fb = ctl.joint_state()
                if args.json:
                    joints = dict(zip(fb.joint_names, fb.positions.tolist(), strict=True))
                    print(json.dumps({"stamp": fb.stamp, "joints": joints}), flush=True)
                else:
                    print(f"t={fb.stamp:.3f} " + " ".join(f"{p:+.4f}" for p in fb.positions), flush=True)
                next_joints = now + 1.0 / args.rate
            stop.wait(0.05)
        return {"message": ""}

    session = _open(args)
    if isinstance(session, str):
        return error_exit(session)
    try:
        with session as ctl:
            action(ctl)
    except ControllerError as exc:
        return error_exit(str(exc), 1)
    return 0

