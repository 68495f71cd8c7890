"""The cell end to end: real processes on loopback Zenoh, robot time sped up."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import yaml
import zenoh
from mcap.reader import make_reader

from cell.evaluation.fold_success import CAUSES, load_success_criteria
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.transport import Wire
from statemachine.machine import ACTIVE_STATES
from tests.bench.bench_cell import min_final_iou
from tests.browser import UNFORMATTED, render, text_drawn
from tests.conftest import DEMO_TIMEOUT_S, REPO, foldcell_argv, wait_until

TIME_SCALE = "20"
pytestmark = pytest.mark.slow


def run_demo(tmp_path: Path, seed: int, garment: str = "all", folding: str = "geometric",
             extra: tuple[str, ...] = ()) -> dict:
    out = tmp_path / f"demo-{seed}-{folding}"
    result = subprocess.run(foldcell_argv("demo", "--garment", garment, "--seed", str(seed), "--time-scale",
                                          TIME_SCALE, "--output", str(out), "--json", "--folding", folding,
                                          *extra),
                            capture_output=True, text=True, timeout=DEMO_TIMEOUT_S)
    assert result.stdout, result.stderr[-3000:]
    summary = json.loads(result.stdout)
    summary["_out"] = out
    summary["_returncode"] = result.returncode
    return summary


# The secured cell (a router, mutual TLS, every process held to its role) folds as the open one does:
# the cell's commands, the camera's images and the recorder's reads all pass the access control.
@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
def test_the_secured_demo_folds_a_towel(tmp_path):
    subprocess.run(foldcell_argv("security", "init", str(tmp_path / "security")), cwd=REPO, check=True,
                   capture_output=True, timeout=60)
    summary = run_demo(tmp_path, 1, "towel", extra=("--security", str(tmp_path / "security")))
    (towel,) = summary["garments"]
    assert towel["outcome"] == "done" and towel["final_iou"] >= min_final_iou("towel"), towel
    assert (summary["_out"] / "logs" / "router.log").is_file()
    with open(summary["_out"] / "session" / "session_0.mcap", "rb") as f:
        topics = {channel.topic.split("/", 3)[3] for _s, channel, _m in make_reader(f).iter_messages()}
    assert {"controller/joint_states", "camera/image", "cell/state", "plan/trajectory"} <= topics


# A scene folded end to end over Zenoh in the geometric world (the cell's logic; the cloth physics
# has its own test below). The success rate over many seeds (84 % today: some
# segmentations leak into the table, some folded garments are mislabelled) is `make bench`'s
# figure (tests/bench/bench_cell.py), not a test's.
@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
@pytest.mark.parametrize("seed", [3])   # seed 1 folds in the secured, MotoROS and wrist demos
def test_demo_folds_every_category(tmp_path, seed):
    summary = run_demo(tmp_path, seed)
    assert [g["garment"] for g in summary["garments"]] == ["towel", "pants", "short-sleeve", "long-sleeve"]
    for g in summary["garments"]:
        assert g["outcome"] == "done", (g["garment"], g["reason"])
        assert g["final_iou"] is not None and g["final_iou"] >= min_final_iou(g["garment"]), (
            g["garment"], g["final_iou"])
        assert g["fold_success"] is None    # the geometric world follows no landmark through the cloth
    assert summary["_returncode"] == 0
    out = summary["_out"]
    assert (out / "summary.json").is_file()
    # the report as a browser shows it: the headline, a row per garment, every fold, a line per joint,
    # an image per perception, no figure left unformatted
    seen = render(out / "report.html", tmp_path / "report.png")
    assert seen.headline == "4 of 4 garments folded" and len(seen.verdicts) == 4, seen
    assert [row[:2] for row in seen.sections["garments"].rows] == [[g["garment"], "done"]
                                                                   for g in summary["garments"]]
    assert len(seen.sections["folds"].rows) >= sum(g["folds_done"] for g in summary["garments"])
    assert sorted(seen.sections["joints"].lines) == sorted(default_robot_config().joint_names)
    assert seen.sections["perceptions"].images == sum(len(g["perceptions"]) for g in summary["garments"])
    assert not UNFORMATTED & set(seen.cells()), seen.cells()
    assert text_drawn(seen.headline_pixels)
    # the session log holds every state transition, every image and every planned trajectory
    counts: dict[str, int] = {}
    transitions = []
    with open(out / "session" / "session_0.mcap", "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            key = channel.topic.split("/", 3)[3]
            counts[key] = counts.get(key, 0) + 1
            if key == "cell/state":
                msg = messages.decode("foldcell_msgs/msg/CellState", message.data)
                transitions.extend((t.source, t.dest, messages.stamp_to_ns(t.stamp)) for t in msg.history)
    states_in_log = [d for _s, d, _t in sorted(set(transitions), key=lambda t: t[2])]
    assert states_in_log.count("done") == len(summary["garments"])
    # a retry within a state (perceiving -> perceiving) is a transition the demo's watcher cannot see
    expected_dests = _runs_of([s for g in summary["garments"] for s in g["states"] if s != "idle"])
    logged = _runs_of([s for s in states_in_log if s != "idle"])
    assert logged == expected_dests
    perceptions = sum(len(g["perceptions"]) for g in summary["garments"])
    assert counts["camera/image"] >= perceptions
    assert counts["perception/observation"] == perceptions
    folds = sum(g["folds_done"] for g in summary["garments"])
    assert counts["plan/trajectory"] >= 4 * folds


def _runs_of(states: list[str]) -> list[str]:
    """The states with repeats in a row collapsed to one."""
    return [s for i, s in enumerate(states) if i == 0 or states[i - 1] != s]


def children_of(pid: int) -> set[int]:
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended while we looked
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


# The cloth-physics world, end to end: the towel's two folds, the cloth following the arms' joint
# states. How well real cloth folds is `make bench`'s figure (bench_physics; 0.7-0.9 against the perfect
# geometric folds, varying with where the joint states were sampled); here both folds must have
# happened: against the ideal quarter-sized towel a flat towel scores 0.25 and a towel folded once 0.5.
@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
def test_the_physics_demo_folds_a_towel(tmp_path):
    summary = run_demo(tmp_path, 1, "towel", folding="physics", extra=("-v",))
    [towel] = summary["garments"]
    # what the world simulated (grasps, folds) explains a failure
    world_log = "".join(line for line in (summary["_out"] / "logs" / "camera.log").open()
                        if "drivers.sim" in line)[-4000:]
    assert towel["outcome"] == "done", (towel["reason"], world_log)
    assert towel["folds_done"] + towel["folds_imperfect"] == 2, (towel, world_log)
    assert towel["final_iou"] is not None and towel["final_iou"] >= 0.6, (towel, world_log)
    # the fold-success measure of the whole recipe, from the world's truth: every landmark within
    # recipe_max_m of the ideal, the area within area_tolerance
    criteria = load_success_criteria()
    measure = towel["fold_success"]
    assert measure is not None, towel
    assert measure["success"] == (measure["landmark_error_cm_max"] <= criteria.recipe_max_m * 100
                                  and abs(measure["area_ratio"] - 1.0) <= criteria.area_tolerance), measure
    assert measure["success"] or measure["cause"] in CAUSES, measure


def test_the_demo_s_processes_die_with_it(tmp_path):
    """A demo killed from outside (a CI timeout, kill -9) leaves no controller, camera or cell behind."""
    demo = subprocess.Popen(foldcell_argv("demo", "--garment", "towel", "--output", str(tmp_path / "d")),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
    try:
        assert wait_until(lambda: len(children_of(demo.pid)) >= 3, 60), "the demo started no processes"
        children = children_of(demo.pid)
    finally:
        demo.kill()
        demo.wait()
    assert wait_until(lambda: not any(alive(c) for c in children), 30), [c for c in children if alive(c)]


class Cell:
    """Controller, camera and cell daemon as processes, and a client that watches the cell."""

    def __init__(self, spawn, endpoint, tmp_path: Path, garment: str = "towel",
                 controller_roles: tuple[str, ...] = ("both",)):
        """`controller_roles`: one controller process (`both`), or a master and a slave."""
        self.spawn = spawn
        self.procs = {
            "controller" if role == "both" else f"controller-{role}": spawn(foldcell_argv(
                "controller", "serve", "--role", role, "--time-scale", "5", *endpoint.args()))
            for role in controller_roles
        }
        self.procs["camera"] = spawn(foldcell_argv("camera", "serve", "--garment", garment, "--seed", "2",
                                                   "--folding", "geometric", *endpoint.args()))
        self.procs["cell"] = spawn(foldcell_argv("run", "--record", str(tmp_path / "s.mcap"),
                                                 *endpoint.args()))
        self.wire = Wire(endpoint.settings(), "test-operator")
        self.states: list[tuple[float, object]] = []
        self.changed = threading.Condition()
        self.wire.subscribe("cell/state", self._on_state)
        alive = lambda: {k.rsplit("/", 1)[1] for k in self.wire.alive()}  # noqa: E731
        assert wait_until(lambda: set(self.procs) <= alive(), 60), \
            {n: p.stderr()[-2000:] for n, p in self.procs.items()}

    def _on_state(self, _k, msg, _r):
        with self.changed:
            self.states.append((time.monotonic(), msg))
            self.changed.notify_all()

    def state(self) -> str:
        with self.changed:
            return self.states[-1][1].state if self.states else ""

    def wait_state(self, names: set[str], timeout: float,
                   fold_index: int | None = None) -> tuple[float, object]:
        """The first state seen in `names` (at fold `fold_index` if given); earlier states are dropped."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for t, msg in self.states:
                    if msg.state in names and fold_index in (None, msg.fold_index):
                        self.states = [s for s in self.states if s[0] >= t]
                        return t, msg
                if time.monotonic() > deadline:
                    raise AssertionError(f"no state in {names} within {timeout} s; last {self.state()}")
                self.changed.wait(0.1)

    def kill(self, name: str) -> None:
        """kill -9, and wait until it is gone; the states it published are forgotten."""
        self.procs[name].popen.send_signal(signal.SIGKILL)
        self.procs[name].popen.wait(30)
        with self.changed:
            self.states = []

    def restart(self, name: str) -> None:
        """The process started again as it was first (same arguments: the same job file)."""
        self.procs[name] = self.spawn(self.procs[name].argv)
        alive = lambda: {k.rsplit("/", 1)[1] for k in self.wire.alive()}  # noqa: E731
        assert wait_until(lambda: name in alive(), 60), self.procs[name].stderr()[-2000:]

    def command(self, command: str, argument: str = ""):
        return self.wire.request("cell/command", messages.new(
            "foldcell_msgs/msg/CellCommand", command=command, argument=argument, client="test"), timeout=10)

    def close(self) -> None:
        self.wire.close()


@pytest.fixture
def cell(spawn, endpoint, tmp_path):
    c = Cell(spawn, endpoint, tmp_path)
    yield c
    c.close()


def test_killing_the_controller_mid_fold_faults_the_cell(cell):
    """How soon (the design's 0.5 s) is `make bench`'s figure (bench_faults)."""
    assert cell.command("fold", "towel").accepted
    cell.wait_state({"folding"}, 60)
    cell.procs["controller"].popen.send_signal(signal.SIGKILL)
    _, msg = cell.wait_state({"fault"}, 30)
    assert "controller" in msg.reason


def test_a_cli_command_and_a_stranger_s_token_do_not_fault_a_fold(cell, endpoint):
    """Only the processes the cell depends on count: a `foldcell controller status` that comes and goes,
    and a stranger's session declaring and withdrawing `alive/controller-x`, leave the fold running."""
    assert cell.command("fold", "towel").accepted
    cell.wait_state({"folding"}, 60)
    status = subprocess.run(foldcell_argv("controller", "status", *endpoint.args()), capture_output=True,
                            text=True, timeout=60)
    assert status.returncode == 0, status.stderr[-2000:]
    assert cell.state() in ACTIVE_STATES, cell.state()  # its exit is no fault
    stranger = zenoh.open(endpoint.settings().zenoh_config())
    try:
        token = stranger.liveliness().declare_token(f"foldcell/{endpoint.cell}/alive/controller-x")
        assert wait_until(lambda: any(k.endswith("/alive/controller-x") for k in cell.wire.alive()), 10)
        token.undeclare()
        assert wait_until(lambda: not any(k.endswith("/alive/controller-x") for k in cell.wire.alive()), 10)
        # both went while the garment was still being folded: the test saw what it means to see
        assert cell.state() in ACTIVE_STATES, cell.state()
    finally:
        stranger.close()
    _, msg = cell.wait_state({"done", "failed", "fault"}, 120)
    assert msg.state == "done", msg.reason


def test_estop_mid_fold_pauses_and_reset_resume_finish_the_garment(cell):
    assert cell.command("fold", "towel").accepted
    cell.wait_state({"folding"}, 60)
    reply = cell.wire.request("controller/command", messages.new(
        "foldcell_msgs/msg/ControllerCommand", command=300001, client="test"), timeout=5)  # ESTOP
    assert reply.result == 0, reply.text
    _, msg = cell.wait_state({"paused"}, 5)
    assert "e-stop" in msg.reason
    refused = cell.command("resume")
    assert not refused.accepted and "e-stop" in refused.text
    assert cell.command("reset").accepted
    assert cell.command("resume").accepted
    _, msg = cell.wait_state({"done", "failed", "fault"}, 120)
    assert msg.state == "done", msg.reason


def test_after_an_estop_the_idle_cell_is_recovered_by_hand_or_by_its_reset(cell, endpoint):
    """No restart and no deadlock: the idle cell gives the lease up (a manual `foldcell controller
    reset` goes through) and its own `reset` clears the controller's e-stop."""
    def controller_cli(*words: str) -> subprocess.CompletedProcess:
        return subprocess.run(foldcell_argv("controller", *words, *endpoint.args()), cwd=REPO,
                              capture_output=True, text=True, timeout=60)

    status: list = []
    cell.wire.subscribe("controller/status", lambda _k, msg, _r: status.append(msg))
    assert cell.command("fold", "towel").accepted
    assert cell.wait_state({"done", "failed", "fault"}, 120)[1].state == "done"
    assert cell.command("reset").accepted
    assert controller_cli("estop").returncode == 0
    refused = cell.command("fold", "towel")
    assert not refused.accepted and "e-stop" in refused.text
    manual = controller_cli("reset")   # by hand: the idle cell holds no lease
    assert manual.returncode == 0, manual.stderr
    assert wait_until(lambda: status and not status[-1].e_stopped, 20)
    # the e-stop is released, the servos are off: the cell does not switch them on by itself
    refused = cell.command("fold", "towel")
    assert not refused.accepted and "servos are off since an e-stop" in refused.text, refused.text
    assert status[-1].drives_powered == 0
    assert controller_cli("estop").returncode == 0
    assert wait_until(lambda: status and status[-1].e_stopped, 20)
    reply = cell.command("reset")      # by the cell: it clears the controller's e-stop, servos on
    assert reply.accepted and "e-stop reset" in reply.text and "servos on" in reply.text, reply.text
    assert wait_until(lambda: not status[-1].e_stopped and status[-1].drives_powered == 1, 20)
    assert cell.command("fold", "towel").accepted
    _, msg = cell.wait_state({"done", "failed", "fault"}, 120)
    assert msg.state == "done", msg.reason


def test_commands_are_checked(cell):
    reply = cell.command("fold", "socks")
    assert not reply.accepted and "unknown garment category 'socks'" in reply.text
    reply = cell.command("resume")
    assert not reply.accepted and "resume is not allowed in state idle" in reply.text
    reply = cell.command("dance")
    assert not reply.accepted and "unknown command" in reply.text
    assert cell.command("status").accepted


def test_a_garment_out_of_reach_ends_in_failed_with_the_reason(spawn, endpoint, tmp_path, monkeypatch):
    # A cell whose table (and the camera above it) stands 1.5 m farther from the robot than usual:
    # every garment on it is beyond both arms' reach.
    config = tmp_path / "config"
    shutil.copytree(REPO / "config", config)
    table = yaml.safe_load((config / "table.yaml").read_text())
    table["near_edge_x"] += 1.5
    (config / "table.yaml").write_text(yaml.safe_dump(table))
    camera = yaml.safe_load((config / "camera.yaml").read_text())
    camera["fixed"]["position"][0] += 1.5
    (config / "camera.yaml").write_text(yaml.safe_dump(camera))
    monkeypatch.setenv("FOLDCELL_CONFIG_DIR", str(config))
    spawn(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "5", *endpoint.args()))
    spawn(foldcell_argv("camera", "serve", "--garment", "towel", "--seed", "2", "--folding", "geometric",
                        *endpoint.args()))
    spawn(foldcell_argv("run", "--no-record", "--job", str(tmp_path / "cell.job.json"), *endpoint.args()))
    with Wire(endpoint.settings(), "test-operator") as wire:
        alive = lambda: {k.rsplit("/", 1)[1] for k in wire.alive()}  # noqa: E731
        assert wait_until(lambda: {"controller", "camera", "cell"} <= alive(), 60)
        states = []
        wire.subscribe("cell/state", lambda k, m, r: states.append(m))
        reply = wire.request("cell/command", messages.new("foldcell_msgs/msg/CellCommand", command="fold",
                                                           argument="towel"), timeout=10)
        assert reply.accepted, reply.text
        assert wait_until(lambda: states and states[-1].state in ("failed", "done", "fault"), 60)
        final = states[-1]
    assert final.state == "failed", final.reason
    assert "unreachable" in final.reason and "table (" in final.reason
