"""The monitor's model without Zenoh: states, joints against limits, controller, rates, liveliness, errors."""

from __future__ import annotations

import json

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
    return MonitorModel(CFG, LIMITS, cell="*", ignore_processes=frozenset({("c1", "cli-monitor-1")}))


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
    assert cell["processes"] == ["cell", "cli-topic-echo-7", "controller"]
    model.on_alive("foldcell/c1/alive/controller", False, 1.0)
    cell = model.snapshot(1.5)["cells"]["c1"]
    assert cell["alive"] and cell["processes_gone"] == [{"name": "controller", "ago_s": 0.5}]
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
        "error [wire] foldcell/c1/cell/state",
    ):
        assert words in text, words
    coloured = "\n".join(render_text(model.snapshot(1.0), colour=True))
    assert "\x1b[31m" in coloured
    assert render_text(MonitorModel(CFG, LIMITS).snapshot(0.0))[-1] == "no cell seen yet"
