"""The session report: per-fold timings from a logged cell/state sequence with known stamps, the joint
trajectory plot, and the HTML that holds them (a real MCAP written with the repo's writer)."""

from __future__ import annotations

import itertools
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from drivers.robot.config import default_robot_config
from drivers.sessions.mcap.reader import iter_messages
from drivers.sessions.mcap.writer import SessionWriter
from drivers.sessions.report import (
    PLOT_MAX_POINTS,
    fold_rows,
    headline,
    joint_plot_svg,
    joint_series,
    look_numbers,
    write_report,
)
from drivers.wire import messages
from tests.browser import UNFORMATTED, VIEWPORT, render, text_drawn

T0 = 1_700_000_000.0   # the cell's clock at the first garment's start
JOINT_SAMPLES = 1000   # at 250 Hz
IMPERFECT = "done, imperfect (outline IoU 0.80 < 0.85)"   # the second fold's report
# (trigger, source, dest, s after T0): a towel in two folds (the second retried once and paused once),
# then a shirt restored after its first fold, in its second when the log ends
TRANSITIONS = [
    ("start", "idle", "perceiving", 0.0), ("perceived", "perceiving", "matching", 1.0),
    ("matched", "matching", "planning", 3.0), ("planned", "planning", "grasping", 3.5),
    ("grasped", "grasping", "folding", 5.0), ("folded", "folding", "verifying", 8.0),
    ("verified", "verifying", "perceiving", 9.0),
    ("perceived", "perceiving", "matching", 10.0), ("matched", "matching", "planning", 11.0),
    ("planned", "planning", "grasping", 12.0), ("retry", "grasping", "perceiving", 13.0),
    ("perceived", "perceiving", "matching", 14.0), ("matched", "matching", "planning", 15.0),
    ("planned", "planning", "paused", 16.0), ("resume", "paused", "grasping", 16.5),
    ("grasped", "grasping", "folding", 17.0), ("folded", "folding", "verifying", 19.0),
    ("verified", "verifying", "done", 20.0),
    ("reset", "done", "idle", 25.0), ("restore", "idle", "paused", 30.0),
    ("resume", "paused", "perceiving", 30.5), ("perceived", "perceiving", "matching", 31.0),
]


def ns(s_after_t0: float) -> int:
    return int((T0 + s_after_t0) * 1e9)


def write_session(path: Path) -> None:
    names = list(default_robot_config().joint_names)
    with SessionWriter(path) as w:

        def put(key: str, type_name: str, msg, t_ns: int) -> None:
            w.write(f"/foldcell/c1/{key}", type_name, messages.msgdef(type_name),
                    messages.encode(type_name, msg), t_ns, t_ns)

        history = []
        for i, (trigger, source, dest, t) in enumerate(TRANSITIONS):
            history.append(messages.new("foldcell_msgs/msg/CellTransition",
                                        stamp=messages.stamp_from_ns(ns(t)), trigger=trigger, source=source,
                                        dest=dest))
            shirt = i >= 19
            fold = 1 if i < 6 else 2
            put("cell/state", "foldcell_msgs/msg/CellState", messages.new(
                "foldcell_msgs/msg/CellState", header=messages.header(ns(t + 0.01)), cell_id="c1", state=dest,
                garment="shirt" if shirt else ("" if dest == "idle" else "towel"), fold_index=fold,
                fold_count=2, attempt=1,
                history=history[-50:]), ns(t + 0.01))
        for fold, attempt, iou, robot, t, outcome in ((1, 1, 0.9, 4.0, 9.05, "done"),
                                                      (2, 2, 0.8, 5.5, 20.05, IMPERFECT)):
            put("cell/fold_report", "foldcell_msgs/msg/FoldReport", messages.new(
                "foldcell_msgs/msg/FoldReport", header=messages.header(ns(t)), garment="towel",
                fold_index=fold, attempt=attempt, outcome=outcome, verify_iou=iou, robot_time=robot), ns(t))
        for i in range(JOINT_SAMPLES):
            position = np.array([math.sin(i / 100 + j) for j in range(len(names))])
            put("controller/joint_states", "sensor_msgs/msg/JointState", messages.new(
                "sensor_msgs/msg/JointState", header=messages.header(ns(i * 0.004)), name=names,
                position=position), ns(i * 0.004))


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("report") / "s.mcap"
    write_session(path)
    return path


def test_fold_rows_from_the_state_transitions_and_fold_reports(session: Path) -> None:
    rows = fold_rows(iter_messages(session))
    assert [(r.garment, r.fold, r.start_s, r.seconds, r.outcome) for r in rows] == [
        ("towel", 1, 0.0, 9.0, "done"), ("towel", 2, 9.0, 11.0, IMPERFECT),
        ("shirt", 2, 30.0, None, "in work")]
    steps = ("perceiving", "matching", "planning", "grasping", "folding", "verifying", "other")
    assert [tuple(round(rows[0].steps_s[s], 3) for s in steps)] == [(1.0, 2.0, 0.5, 1.5, 3.0, 1.0, 0.0)]
    assert [tuple(round(rows[1].steps_s[s], 3) for s in steps)] == [(2.0, 2.0, 2.0, 1.5, 2.0, 1.0, 0.5)]
    assert (round(rows[2].steps_s["other"], 3), round(rows[2].steps_s["perceiving"], 3)) == (0.5, 0.5)
    assert [(r.attempt, r.verify_iou, r.robot_time_s) for r in rows] == [(1, 0.9, 4.0), (2, 0.8, 5.5),
                                                                         (None, None, None)]


def polylines(svg: str) -> list[ET.Element]:
    return ET.fromstring(svg).findall("{http://www.w3.org/2000/svg}polyline")


def test_joint_plot_has_a_decimated_polyline_per_joint(session: Path) -> None:
    names = list(default_robot_config().joint_names)
    series = joint_series(iter_messages(session))
    assert list(series) == ["/foldcell/c1/controller/joint_states"]
    lines = polylines(joint_plot_svg(series["/foldcell/c1/controller/joint_states"].joints))
    assert [p.get("data-joint") for p in lines] == names
    kept = list(range(0, JOINT_SAMPLES, -(-JOINT_SAMPLES // PLOT_MAX_POINTS)))  # every k-th, k = ceil
    assert len(kept) <= PLOT_MAX_POINTS
    for j, line in enumerate(lines):
        xy = [tuple(map(float, p.split(","))) for p in line.get("points", "").split()]
        assert len(xy) == len(kept)
        assert all(a[0] < b[0] for a, b in itertools.pairwise(xy))  # time runs right
        logged = [math.sin(i / 100 + j) for i in kept]
        # y is the kept samples' positions, scaled (the highest drawn highest: smallest y)
        slope, offset = np.polyfit(logged, [y for _, y in xy], 1)
        assert slope < 0 and np.abs(np.polyval((slope, offset), logged) - [y for _, y in xy]).max() < 0.1


def test_the_html_report_holds_the_fold_table_and_the_plot(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    write_report(session, {"garments": [], "time_scale": 1.0, "seed": 0, "session_log": str(session)}, out)
    page = out.read_text()
    assert "<h2>Every fold</h2>" in page and "<h2>Joint trajectories</h2>" in page
    table = page[page.index('<table class="folds">'):]
    table = table[: table.index("</table>") + len("</table>")]
    rows = ET.fromstring(table).findall("tr")
    assert [c.text for c in rows[2].findall("td")] == [
        "towel", "2", "9.00", IMPERFECT, "2.00", "2.00", "2.00", "0.00", "1.50", "2.00", "1.00", "0.50",
        "11.00", "2", "0.800", "5.50"]
    svgs = re.findall(r"<svg.*?</svg>", page, re.S)
    # a plot per control group, its joints and no other's: each a few lines, told apart by colour
    groups = default_robot_config().groups
    assert [[p.get("data-joint") for p in polylines(svg)] for svg in svgs] == [list(g.joints) for g in groups]
    for svg in svgs:
        colours = [p.get("stroke") for p in polylines(svg)]
        assert len(set(colours)) == len(colours), colours
        root = ET.fromstring(svg)
        # the towel was taken up as the joint states began; the shirt after they end is not drawn
        marks = root.findall("{http://www.w3.org/2000/svg}line[@class='mark']")
        texts = [t.text for t in root.findall("{http://www.w3.org/2000/svg}text")]
        assert len(marks) == 1 and "towel" in texts and "shirt" not in texts, texts
        # both axes are marked at round values: position (rad) and time (s) over the 4 s of joint states
        ticks = [float(t.text or "") for t in root.findall("{http://www.w3.org/2000/svg}text[@class='position']")]
        assert len(ticks) >= 3 and all(abs(v * 2 - round(v * 2)) < 1e-9 for v in ticks), ticks
        times = [float(t.text or "") for t in root.findall("{http://www.w3.org/2000/svg}text[@class='time']")]
        span = (JOINT_SAMPLES - 1) * 0.004
        assert len(times) >= 3 and times[0] == 0.0 and span - times[-1] < span / 4, times
        assert all(abs(v * 2 - round(v * 2)) < 1e-9 for v in times), times


def test_a_garment_seen_again_after_as_many_folds_is_numbered_as_another_look() -> None:
    looks = [("c1", "towel", 0), ("c1", "towel", 0), ("c1", "towel", 1), ("c2", "towel", 1),
             ("c1", "towel", 1), ("c1", "towel", 2), ("c1", "pants", 0),
             ("c1", "towel", 0), ("c1", "towel", 0)]   # the next towel: counted afresh
    assert look_numbers(looks) == [1, 2, 1, 1, 2, 1, 1, 1, 2]


def test_the_headline_counts_garments_folded_and_each_verdict_counts_every_fold() -> None:
    def garment(name: str, outcome: str, done: int, imperfect: int, reason: str = "") -> dict:
        return {"garment": name, "outcome": outcome, "folds_done": done, "folds_imperfect": imperfect,
                "reason": reason}

    page = headline([garment("towel", "done", 2, 0), garment("long-sleeve", "done", 3, 3),
                     garment("pants", "fault", 1, 0, "lease lost: <the cell> stopped")])
    assert page.startswith('<p class="headline">2 of 3 garments folded (1 with imperfect folds)</p>')
    assert "<li><b>towel</b> done (2 folds)</li>" in page
    assert "<li><b>long-sleeve</b> done (3 folds, 3 of them imperfect)</li>" in page
    assert "<li><b>pants</b> fault (1 fold): lease lost: &lt;the cell&gt; stopped</li>" in page


def summary_garment(name: str, outcome: str, folds: int, reason: str = "") -> dict:
    """A garment as the demo's summary gives it, with the figures a failed garment has not measured."""
    done = outcome == "done"
    return {"garment": name, "outcome": outcome, "folds_done": folds, "folds_imperfect": 0, "reason": reason,
            "final_iou": 0.91 if done else None, "fold_success": None,
            "landmark_error_cm": {"median": 1.5 if done else None}, "compute_s": {"perceive": 0.4},
            "robot_time_s": 9.5 if done else None, "wall_time_s": 20.0, "notes": []}


# The page as a browser draws it: the headline, every section holding what was logged, no figure left
# unformatted, and the screenshot shows the headline's text.
def test_the_report_in_a_headless_browser(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    garments = [summary_garment("towel", "done", 2), summary_garment("shirt", "fault", 0, "lease lost")]
    write_report(session, {"garments": garments, "time_scale": 1.0, "seed": 0, "session_log": str(session)},
                 out)
    seen = render(out, tmp_path / "report.png")
    assert seen.headline == "1 of 2 garments folded"
    assert seen.verdicts == ["towel done (2 folds)", "shirt fault (0 folds): lease lost"]
    assert [row[:2] for row in seen.sections["garments"].rows] == [["towel", "done"], ["shirt", "fault"]]
    folds = [["towel", "1"], ["towel", "2"], ["shirt", "2"]]   # as TRANSITIONS has them
    assert [row[:2] for row in seen.sections["folds"].rows] == folds
    assert sorted(seen.sections["joints"].lines) == sorted(default_robot_config().joint_names)
    assert seen.sections["perceptions"].empty == ["No perception was recorded."]
    assert not UNFORMATTED & set(seen.cells()), seen.cells()
    assert text_drawn(seen.headline_pixels)
    assert seen.screenshot.shape[1] == VIEWPORT["width"]
