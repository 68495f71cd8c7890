"""The monitor's model without Zenoh: states, joints against limits, controller, rates, liveliness, errors."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from drivers.sessions.monitor.config import load_monitor_config
from drivers.sessions.monitor.model import JointLimit, MonitorModel
from drivers.sessions.monitor.render import render_text
from drivers.wire import messages
from tests.nodes.fake_cell import STATES, cell_state

CFG = load_monitor_config()
LIMITS = {"a": JointLimit(-1.0, 1.0), "b": JointLimit(0.0, 2.0)}


def enc(type_name: str, msg) -> bytes:
    return messages.encode(type_name, msg)


def joints(positions: list[float]) -> bytes:
    return enc(
        "sensor_msgs/msg/JointState",
        messages.new(
            "sensor_msgs/msg/JointState",
            name=["a", "b", "c"][: len(positions)],
            position=np.array(positions),
            velocity=np.zeros(len(positions)),
            effort=np.zeros(len(positions)),
        ),
    )


@pytest.fixture
def model() -> MonitorModel:
    return MonitorModel(
        CFG, LIMITS, cell="*", ignore_processes=frozenset({("c1", "cli-monitor-1")}), wall_clock=noon_at
    )


def noon_at() -> float:
    """A wall clock reading 12:00:00 local time whenever asked."""
    return time.mktime((2024, 5, 1, 12, 0, 0, 0, 0, -1))


def test_state_sequence_history_and_fold_step(model: MonitorModel) -> None:
    for i in range(1, len(STATES) + 1):
        payload = enc("foldcell_msgs/msg/CellState", cell_state("c1", list(STATES[:i]), 1000 + i))
        model.on_sample("foldcell/c1/cell/state", payload, "foldcell_msgs/msg/CellState", float(i))
        # the periodic 2 Hz repeat of the same state must not add to the sequence
        model.on_sample("foldcell/c1/cell/state", payload, "", float(i) + 0.5)
    cell = model.snapshot(10.0)["cells"]["c1"]
    assert cell["states_seen"] == list(STATES)
    st = cell["state"]
    assert st["state"] == "done" and st["garment"] == "towel" and st["fold_count"] == 2
    assert [h["dest"] for h in st["history"]] == list(STATES[1:])
    assert cell["topics"]["cell/state"]["count"] == 2 * len(STATES)


def test_joints_against_limits(model: MonitorModel) -> None:
    model.on_sample("foldcell/c1/controller/joint_states", joints([0.0, 1.99, 5.0]), "", 1.0)
    rows = {j["name"]: j for j in model.snapshot(1.0)["cells"]["c1"]["joints"]}
    assert (
        rows["a"]["fraction"] == pytest.approx(0.5)
        and not rows["a"]["near_limit"]
        and not rows["a"]["outside"]
    )
    assert rows["b"]["near_limit"] and not rows["b"]["outside"]
    assert rows["c"] == {"name": "c", "position": 5.0}  # no limits known: position only
    model.on_sample("foldcell/c1/controller/joint_states", joints([-1.5, 1.0]), "", 2.0)
    rows = {j["name"]: j for j in model.snapshot(2.0)["cells"]["c1"]["joints"]}
    assert rows["a"]["outside"] and rows["a"]["near_limit"]


def test_controller_status_fields(model: MonitorModel) -> None:
    status = messages.new(
        "foldcell_msgs/msg/ControllerStatus",
        drives_powered=1,
        e_stopped=1,
        in_error=1,
        error_code=4107,
        alarm_text="OUT OF RANGE",
        in_motion=0,
        mode=2,
        motion_possible=0,
        held=-1,
        trajectory_mode=0,
        lease_holder="cell-42",
        time_scale=1.0,
    )
    model.on_sample(
        "foldcell/c1/controller/status", enc("foldcell_msgs/msg/ControllerStatus", status), "", 1.0
    )
    ctl = model.snapshot(1.0)["cells"]["c1"]["controller"]
    assert ctl["servo"] is True and ctl["e_stop"] is True and ctl["alarm"] is True
    assert ctl["alarm_code"] == 4107 and ctl["alarm_text"] == "OUT OF RANGE"
    assert ctl["in_motion"] is False and ctl["held"] is None and ctl["mode"] == "play"
    assert ctl["lease_holder"] == "cell-42"


def test_topic_rate_and_age_over_the_window(model: MonitorModel) -> None:
    rate = 250.0
    payload = joints([0.0, 1.0])
    n = int(rate * 4)
    for i in range(n):
        model.on_sample("foldcell/c1/controller/joint_states", payload, "", i / rate)
    t = model.snapshot(n / rate)["cells"]["c1"]["topics"]["controller/joint_states"]
    assert t["count"] == n
    assert t["rate_hz"] == pytest.approx(rate, rel=0.02)
    assert not t["stale"]
    later = model.snapshot(n / rate + CFG.stale_after_s + 1.0)["cells"]["c1"]["topics"][
        "controller/joint_states"
    ]
    assert later["stale"] and later["rate_hz"] == 0.0 and later["age_s"] > CFG.stale_after_s


def test_liveliness_alive_gone_replay_and_observers(model: MonitorModel) -> None:
    model.on_alive("foldcell/c1/alive/controller", True, 0.0)
    model.on_alive("foldcell/c1/alive/cell", True, 0.0)
    model.on_alive("foldcell/c1/alive/cli-monitor-1", True, 0.0)  # the monitor itself: ignored
    model.on_alive("foldcell/c1/alive/cli-topic-echo-7", True, 0.0)  # an observer
    cell = model.snapshot(0.1)["cells"]["c1"]
    assert cell["alive"] and not cell["gone"] and not cell["replay"]
    # a tool (cli-*) is listed apart from the cell's own processes
    assert cell["processes"] == ["cell", "controller"] and cell["tools"] == ["cli-topic-echo-7"]
    model.on_alive("foldcell/c1/alive/controller", False, 1.0)
    cell = model.snapshot(1.5)["cells"]["c1"]
    assert cell["alive"]
    assert cell["processes_gone"] == [{"name": "controller", "ago_s": 0.5, "cell_lost": False}]
    model.on_alive("foldcell/c1/alive/cell", False, 2.0)
    cell = model.snapshot(2.0)["cells"]["c1"]
    assert cell["gone"] and not cell["alive"]  # only an observer is left
    model.on_alive("foldcell/c2/alive/cli-replay-99", True, 3.0)
    assert model.snapshot(3.0)["cells"]["c2"]["replay"]


@pytest.mark.parametrize(
    "key,payload,encoding,words",
    [
        ("foldcell/c1/cell/state", b"\x00\x01garbage", "", "CDR"),
        ("foldcell/c1/controller/joint_states", b"", "", ""),
        ("foldcell/c1/controller/status", b"\x00\x01\x00\x00\x01", "", ""),
        (
            "foldcell/c1/cell/log",
            enc("foldcell_msgs/msg/CellState", cell_state("c1", ["idle"], 1)),
            "foldcell_msgs/msg/CellState",
            "rcl_interfaces/msg/Log",
        ),
        ("foldcell/c1/not/a/key", b"x", "", "registry"),
    ],
)
def test_malformed_samples_are_shown_and_the_model_goes_on(
    model: MonitorModel, key: str, payload: bytes, encoding: str, words: str
) -> None:
    model.on_sample(key, payload, encoding, 1.0)
    good = enc("foldcell_msgs/msg/CellState", cell_state("c1", ["idle", "perceiving"], 2))
    model.on_sample("foldcell/c1/cell/state", good, "", 2.0)
    cell = model.snapshot(2.0)["cells"]["c1"]
    assert cell["errors_total"] == 1
    err = cell["errors"][0]
    assert err["source"] == "wire" and err["where"] == key and words in err["text"] and err["text"]
    assert cell["state"]["state"] == "perceiving"  # still going
    json.dumps(model.snapshot(2.0))  # JSON-able with errors in it


def test_log_errors_from_warn_up_and_bounded(model: MonitorModel) -> None:
    for i in range(CFG.max_errors + 5):
        level = 40 if i % 2 else 20
        log = messages.new("rcl_interfaces/msg/Log", level=level, name="cell", msg=f"line {i}")
        model.on_sample("foldcell/c1/cell/log", enc("rcl_interfaces/msg/Log", log), "", float(i))
    cell = model.snapshot(100.0)["cells"]["c1"]
    assert all(e["source"] == "log" and e["level"] >= CFG.error_log_level for e in cell["errors"])
    assert len(cell["errors"]) <= CFG.max_errors
    errors_sent = [i for i in range(CFG.max_errors + 5) if i % 2]
    assert [e["text"] for e in cell["errors"]] == [f"line {i}" for i in errors_sent][-CFG.max_errors :]
    assert cell["errors_total"] == len(errors_sent)


def test_many_cells_are_kept_apart(model: MonitorModel) -> None:
    rng = np.random.default_rng(7)
    expected: dict[str, list[str]] = {}
    for _ in range(300):
        cell = f"c{int(rng.integers(5))}"
        state = STATES[int(rng.integers(len(STATES)))]
        seq = expected.setdefault(cell, [])
        if not seq or seq[-1] != state:
            seq.append(state)
        payload = enc("foldcell_msgs/msg/CellState", cell_state(cell, [state], 1))
        model.on_sample(f"foldcell/{cell}/cell/state", payload, "", 1.0)
    snap = model.snapshot(1.0)
    assert {c: v["states_seen"][-len(expected[c]) :] for c, v in snap["cells"].items()} == expected


def test_render_text_shows_what_matters(model: MonitorModel) -> None:
    model.on_alive("foldcell/c1/alive/cell", True, 0.0)
    model.on_sample(
        "foldcell/c1/cell/state",
        enc("foldcell_msgs/msg/CellState", cell_state("c1", ["idle", "folding"], 1)),
        "",
        0.5,
    )
    model.on_sample("foldcell/c1/controller/joint_states", joints([0.0, 1.99]), "", 0.5)
    model.on_sample("foldcell/c1/cell/state", b"bad", "", 0.6)
    model.on_alive("foldcell/c1/alive/cell", False, 0.7)
    text = "\n".join(render_text(model.snapshot(1.0)))
    for words in (
        "cell c1",
        "GONE",
        "folding",
        "fold 0/2",
        "LIMIT",
        "controller/joint_states",
        "error [wire] (11:59:59) foldcell/c1/cell/state",
    ):
        assert words in text, words
    coloured = "\n".join(render_text(model.snapshot(1.0), colour=True))
    assert "\x1b[31m" in coloured
    assert render_text(MonitorModel(CFG, LIMITS).snapshot(0.0))[-1] == "no cell seen yet"


def test_a_fault_keeps_its_first_reason_and_long_lines_wrap(model: MonitorModel) -> None:
    first = ("lease lost: the controller no longer saw alive/cell (silent for 0.41 s) "
             + " ".join(["and more"] * 12))
    later = "process camera is gone (not back within 1 s)"
    for stamp, (state, reason) in enumerate([("folding", ""), ("fault", first), ("fault", later),
                                             ("fault", later)]):
        msg = cell_state("c1", ["idle", state], 10 + stamp)
        msg.reason = reason
        model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", msg), "", 1.0 + stamp)
    st = model.snapshot(5.0)["cells"]["c1"]["state"]
    assert (st["reason"], st["later_reason"]) == (first, later)
    lines = render_text(model.snapshot(5.0), width=80)
    assert all(len(line) <= 80 for line in lines), lines
    # the whole reason is there, over several lines, the first cause before the later one
    text = " ".join(line.strip() for line in lines)
    assert f"reason: {first} (since: {later})" in text, text
    # a new fault (after another state) is its own: its reason is the first again
    msg = cell_state("c1", ["fault", "idle"], 20)
    model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", msg), "", 6.0)
    msg = cell_state("c1", ["idle", "fault"], 21)
    msg.reason = later
    model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", msg), "", 7.0)
    st = model.snapshot(7.0)["cells"]["c1"]["state"]
    assert (st["reason"], st["later_reason"]) == (later, "")


def test_gone_list_keeps_the_cells_processes_a_while_and_no_command_processes(model: MonitorModel) -> None:
    model.on_alive("foldcell/c1/alive/cell", True, 0.0)
    for i in range(50):  # every `foldcell topic pub` or `log info` comes and goes
        model.on_alive(f"foldcell/c1/alive/cli-topic-pub-{i}", True, float(i))
        model.on_alive(f"foldcell/c1/alive/cli-topic-pub-{i}", False, float(i) + 0.5)
    cell = model.snapshot(60.0)["cells"]["c1"]
    assert cell["processes"] == ["cell"] and cell["processes_gone"] == []
    crashes = CFG.max_gone + 3
    for i in range(crashes):
        model.on_alive(f"foldcell/c1/alive/camera-{i}", True, 100.0)
        model.on_alive(f"foldcell/c1/alive/camera-{i}", False, 100.0 + i)
    gone = model.snapshot(100.0 + crashes)["cells"]["c1"]["processes_gone"]
    assert sorted(p["name"] for p in gone) == sorted(f"camera-{i}" for i in range(3, crashes))
    assert {p["name"]: p["ago_s"] for p in gone}["camera-3"] == crashes - 3
    model.on_alive("foldcell/c1/alive/cell", False, 200.0)
    late = 200.0 + CFG.gone_keep_s + 1.0
    cell = model.snapshot(late)["cells"]["c1"]
    assert cell["processes_gone"] == [] and cell["gone"] and not cell["alive"]  # still a dead cell
    assert len(model.cells["c1"].processes) == 0


def test_a_repeated_error_is_shown_once_with_its_count_and_last_time(model: MonitorModel) -> None:
    def log(text: str, at: float) -> None:
        msg = messages.new("rcl_interfaces/msg/Log", level=40, name="cell", msg=text)
        model.on_sample("foldcell/c1/cell/log", enc("rcl_interfaces/msg/Log", msg), "", at)

    for i in range(CFG.max_errors + 20):
        log("the slave answered too late; retry", float(i))
    log("camera timeout", 40.0)
    log("the slave answered too late; retry", 50.0)
    cell = model.snapshot(52.0)["cells"]["c1"]
    assert [(e["text"], e["count"]) for e in cell["errors"]] == [
        ("camera timeout", 1),
        ("the slave answered too late; retry", CFG.max_errors + 21),
    ]
    slave = cell["errors"][-1]
    assert slave["first_at_s"] == 0.0 and slave["ago_s"] == 2.0 and slave["last_time"] == "11:59:58"
    assert cell["errors_total"] == CFG.max_errors + 22
    text = "\n".join(render_text(model.snapshot(52.0)))
    assert text.count("slave answered too late") == 1
    assert f"({CFG.max_errors + 21}x, last 11:59:58) cell: the slave answered too late" in text


def gripper(arm: str, closed: bool, opening: float) -> bytes:
    unit = messages.new("geometry_msgs/msg/Quaternion", w=1.0)
    pose = messages.new("geometry_msgs/msg/Pose", orientation=unit)
    msg = messages.new(
        "foldcell_msgs/msg/GripperState", arm=arm, closed=closed, opening=opening, tcp_pose=pose
    )
    return enc("foldcell_msgs/msg/GripperState", msg)


def test_grippers_per_arm(model: MonitorModel) -> None:
    model.on_sample("foldcell/c1/controller/gripper/r1", gripper("r1", False, 0.08), "", 1.0)
    model.on_sample("foldcell/c1/controller/gripper/r2", gripper("r2", False, 0.08), "", 1.0)
    model.on_sample("foldcell/c1/controller/gripper/r1", gripper("r1", True, 0.0), "", 2.0)
    cell = model.snapshot(2.0)["cells"]["c1"]
    assert cell["grippers"] == {
        "r1": {"closed": True, "opening_m": 0.0},
        "r2": {"closed": False, "opening_m": 0.08},
    }
    assert "grippers r1 closed 0 mm  r2 open 80 mm" in "\n".join(render_text(model.snapshot(2.0)))


def garment_state(state: str, history: list[tuple], stamp_s: float, fold_index: int = 1,
                  garment: str = "towel") -> bytes:
    """A CellState stamped `stamp_s` (the cell's clock) with transitions (trigger, dest, stamp_s) or
    (trigger, source, dest, stamp_s)."""
    msg = messages.new(
        "foldcell_msgs/msg/CellState",
        header=messages.header(int(stamp_s * 1e9)),
        cell_id="c1",
        state=state,
        garment=garment,
        fold_index=fold_index,
        fold_count=2,
        attempt=1,
        history=[
            messages.new("foldcell_msgs/msg/CellTransition", stamp=messages.stamp_from_ns(int(t[-1] * 1e9)),
                         trigger=t[0], source=t[1] if len(t) == 4 else "", dest=t[-2])
            for t in history
        ],
    )
    return enc("foldcell_msgs/msg/CellState", msg)


def test_garment_elapsed_time_from_the_cells_own_stamps(model: MonitorModel) -> None:
    # the cell's clock is far from the monitor's: only differences of its stamps count
    cell_t0 = 1_700_000_000.0
    started = [("reset", "idle", cell_t0 - 99.0), ("start", "perceiving", cell_t0)]
    model.on_sample("foldcell/c1/cell/state", garment_state("matching", started, cell_t0 + 30.0), "", 500.0)
    assert model.snapshot(505.0)["cells"]["c1"]["garment_elapsed_s"] == 35.0
    assert "garment towel 35.0 s" in "\n".join(render_text(model.snapshot(505.0)))
    assert "garment towel 1:35" in "\n".join(render_text(model.snapshot(565.0)))
    ended = [*started, ("verified", "done", cell_t0 + 50.0)]
    model.on_sample("foldcell/c1/cell/state", garment_state("done", ended, cell_t0 + 52.0), "", 523.0)
    assert model.snapshot(900.0)["cells"]["c1"]["garment_elapsed_s"] == 50.0  # stopped at done
    model.on_sample("foldcell/c1/cell/state", garment_state("done", ended, cell_t0 + 60.0), "", 531.0)
    assert model.snapshot(900.0)["cells"]["c1"]["garment_elapsed_s"] == 50.0
    idle = messages.new("foldcell_msgs/msg/CellState", header=messages.header(), cell_id="c1", state="idle")
    model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", idle), "", 600.0)
    assert model.snapshot(600.0)["cells"]["c1"]["garment_elapsed_s"] is None


def fold_cycle(first: str, t0: float) -> list[tuple[str, str, str, float]]:
    """The transitions of one fold's steps from `first` (start or verified) at t0, one second apart."""
    steps = [(first, "idle" if first == "start" else "verifying", "perceiving"),
             ("perceived", "perceiving", "matching"), ("matched", "matching", "planning"),
             ("planned", "planning", "grasping"), ("grasped", "grasping", "folding"),
             ("folded", "folding", "verifying")]
    return [(trigger, source, dest, t0 + i) for i, (trigger, source, dest) in enumerate(steps)]


def test_elapsed_time_of_each_fold_from_the_cells_state_sequence(model: MonitorModel) -> None:
    t0 = 1_700_000_000.0  # the cell's clock; the monitor's is at 500
    fold1 = fold_cycle("start", t0)
    fold2 = [*fold1, *fold_cycle("verified", t0 + 8.0)[:2]]  # fold 1 checked at t0 + 8
    def feed(state: str, history: list, stamp: float, fold: int, at: float, garment: str = "towel") -> dict:
        model.on_sample("foldcell/c1/cell/state", garment_state(state, history, stamp, fold, garment), "", at)
        return model.snapshot(at + 3.0)["cells"]["c1"]

    cell = feed("perceiving", fold1[:1], t0 + 0.5, 1, 500.0)
    assert cell["folds"] == [{"fold": 1, "elapsed_s": 3.5, "outcome": ""}] and cell["fold_elapsed_s"] == 3.5
    cell = feed("matching", fold2, t0 + 10.0, 2, 500.0)
    assert cell["folds"] == [{"fold": 1, "elapsed_s": 8.0, "outcome": "done"},
                             {"fold": 2, "elapsed_s": 5.0, "outcome": ""}]  # 2 s in the cell, 3 since
    assert cell["fold_elapsed_s"] == 5.0
    text = "\n".join(render_text(model.snapshot(503.0)))
    assert "fold 2/2 5.0 s attempt 1" in text and "folds 1: 8.0 s done  2: 5.0 s in work" in text
    # a retry stays in the fold; the last check ends fold and garment; later samples keep the times
    finished = [*fold2, ("retry", "matching", "perceiving", t0 + 12.0),
                *fold_cycle("perceived", t0 + 13.0)[1:], ("verified", "verifying", "done", t0 + 20.0)]
    cell = feed("done", finished, t0 + 21.0, 2, 510.0)
    assert [(f["fold"], f["elapsed_s"], f["outcome"]) for f in cell["folds"]] == [(1, 8.0, "done"),
                                                                                (2, 12.0, "done")]
    assert cell["fold_elapsed_s"] == 12.0
    # the garment's start and fold 1 left the history: what was known is kept
    cell = feed("done", finished[-3:], t0 + 30.0, 2, 520.0)
    assert [(f["fold"], f["elapsed_s"]) for f in cell["folds"]] == [(1, 8.0), (2, 12.0)]
    # the next garment starts with fold 1 alone
    cell = feed("perceiving", [*finished, ("start", "done", "perceiving", t0 + 40.0)], t0 + 41.0, 1, 530.0,
                "shirt")
    assert cell["folds"] == [{"fold": 1, "elapsed_s": 4.0, "outcome": ""}]
    # a restored garment goes on with the fold the cell says, timed from the restore
    restored = [("reset", "done", "idle", t0 + 50.0), ("restore", "idle", "paused", t0 + 60.0)]
    cell = feed("paused", restored, t0 + 61.0, 2, 540.0)
    assert cell["folds"] == [{"fold": 2, "elapsed_s": 4.0, "outcome": ""}] and cell["fold_elapsed_s"] == 4.0
    idle = messages.new("foldcell_msgs/msg/CellState", header=messages.header(), cell_id="c1", state="idle")
    model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", idle), "", 600.0)
    cell = model.snapshot(600.0)["cells"]["c1"]
    assert cell["folds"] == [] and cell["fold_elapsed_s"] is None


# The cell's own view rules: a process it says it lost is gone though this monitor still sees its token
# (the monitor's link may outlive the cell's), until the cell has it back.
def test_a_process_the_cell_lost_is_gone_whatever_its_token_here(model: MonitorModel) -> None:
    for process in ("cell", "camera", "controller"):
        model.on_alive(f"foldcell/c1/alive/{process}", True, 0.0)

    def state_saying_lost(lost: list[str], at: float) -> None:
        msg = cell_state("c1", ["idle", "fault"], int(at))
        msg.processes_lost = lost
        model.on_sample("foldcell/c1/cell/state", enc("foldcell_msgs/msg/CellState", msg), "", at)

    state_saying_lost(["camera"], 5.0)
    later = 5.0 + CFG.gone_keep_s + 10.0    # past the gone list's keep: the cell still says it is lost
    state_saying_lost(["camera"], later)
    cell = model.snapshot(later)["cells"]["c1"]
    assert cell["processes"] == ["cell", "controller"]
    assert cell["processes_gone"] == [{"name": "camera", "ago_s": later - 5.0, "cell_lost": True}]
    assert any("gone: camera (" in line and "the cell lost it" in line
               for line in render_text(model.snapshot(later), width=120))
    state_saying_lost([], later + 1.0)
    cell = model.snapshot(later + 1.0)["cells"]["c1"]
    assert cell["processes"] == ["camera", "cell", "controller"] and cell["processes_gone"] == []
