"""A session's perceptions, and the demo's HTML report: the summary, the timings of every fold (from
the cell's state transitions and fold reports), the joint trajectories, and every perception's image
with its matched model drawn on it."""

from __future__ import annotations

import base64
import html
import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drivers.common.labels import Box, LabelStyle, draw_labels
from drivers.common.outcomes import FoldOutcome
from drivers.robot.config import default_robot_config
from drivers.sessions.folds import split_garments, transitions_of
from drivers.sessions.mcap.bag import find_session
from drivers.sessions.mcap.reader import LoggedMessage, iter_messages
from drivers.sessions.replay import topic_key
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import split_key

REPORT_WIDTH = 640          # px of each image in the report
JPEG_QUALITY = 80
POLYGON_BGR = (255, 128, 20)
LANDMARK_BGR = (40, 40, 255)
MARKER_RADIUS_PX = 9
LABEL_STYLE = LabelStyle(scale=0.9, thickness=2)
LABEL_GAP_PX = 12           # between a landmark and its name


def overlay(png: bytes, observation: Any) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError("the logged image does not decode")
    pts = np.array([[lm.x_px, lm.y_px] for lm in observation.landmarks], dtype=np.float32)
    garment = np.zeros(image.shape[:2], np.uint8)
    if len(pts):
        cv2.polylines(image, [np.round(pts).astype(np.int32)], True, POLYGON_BGR, 4, cv2.LINE_AA)
        cv2.fillPoly(garment, [np.round(pts).astype(np.int32)], 1)
    centres = [(round(lm.x_px), round(lm.y_px)) for lm in observation.landmarks]
    for centre in centres:
        cv2.circle(image, centre, MARKER_RADIUS_PX, LANDMARK_BGR, 3, cv2.LINE_AA)
    markers = [Box(x - MARKER_RADIUS_PX, y - MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX)
               for x, y in centres]
    draw_labels(image, [lm.name for lm in observation.landmarks], centres, LABEL_STYLE,
                [LANDMARK_BGR] * len(centres), gap=LABEL_GAP_PX, obstacles=markers,
                away_from=tuple(pts.mean(axis=0)) if len(pts) else None, keep_off=garment.astype(bool))
    scale = REPORT_WIDTH / image.shape[1]
    return cv2.resize(image, (REPORT_WIDTH, int(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)


def _data_uri(image: np.ndarray) -> str:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode() if ok else ""


IMAGE_KEY = "camera/image"
OBSERVATION_KEY = "perception/observation"
STATE_KEY = "cell/state"
FOLD_REPORT_KEY = "cell/fold_report"
JOINTS_KEY = "controller/joint_states"
STEP_STATES = ("perceiving", "matching", "planning", "pulling", "grasping", "folding", "verifying")
PLOT_MAX_POINTS = 600       # samples per joint in the trajectory plot (the stream is 250 Hz)
PLOT_SIZE_PX = (960, 300)
PLOT_MARGIN_PX = (56, 22, 150, 32)  # left, top (the title), right (the legend), bottom
PLOT_Y_TICKS = 6            # round position values marked, at most
PLOT_X_TICKS = 10           # round times marked, at most
PLOT_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                "#7f7f7f", "#bcbd22", "#17becf")


@dataclass(frozen=True)
class LoggedPerception:
    """A logged `camera/image` and the `perception/observation` of the same cell with its stamp
    (None when none was logged)."""

    message: LoggedMessage
    image: Any
    observation: Any | None

    @property
    def cell(self) -> str:
        return cell_of_topic(self.message.topic)


def cell_of_topic(topic: str) -> str:
    try:
        return split_key(topic.lstrip("/"))[0]
    except WireError:
        return ""


def image_stamp_ns(logged: LoggedMessage, decoded: Any) -> int:
    """The stamp an image and its observation share: the header's, or the sender's stamp."""
    return messages.message_stamp_ns(decoded) or logged.publish_time_ns


def logged_perceptions(logged: Iterable[LoggedMessage]) -> list[LoggedPerception]:
    """Every logged image in order, with the observation made from it."""
    images: list[tuple[LoggedMessage, Any]] = []
    observations: dict[tuple[str, int], Any] = {}
    for m in logged:
        key = topic_key(m.topic)
        if key == IMAGE_KEY:
            images.append((m, messages.decode(m.type_name, m.data, m.topic)))
        elif key == OBSERVATION_KEY:
            obs = messages.decode(m.type_name, m.data, m.topic)
            observations[(cell_of_topic(m.topic), image_stamp_ns(m, obs))] = obs
    return [LoggedPerception(m, image, observations.get((cell_of_topic(m.topic), image_stamp_ns(m, image))))
            for m, image in images]


@dataclass(frozen=True)
class FoldRow:
    """One fold as the session log tells it: its time in each step (s), from the cell's transitions,
    and what its fold report said."""

    cell: str
    garment: str
    fold: int
    start_s: float                # since the first garment of the session was taken up
    seconds: float | None         # None: the log ends before the fold does
    outcome: str
    steps_s: dict[str, float] = field(default_factory=dict)  # work state -> s; `other`: paused, fault
    attempt: int | None = None
    verify_iou: float | None = None
    robot_time_s: float | None = None


def fold_rows(logged: Iterable[LoggedMessage]) -> list[FoldRow]:
    """Every fold of every garment of the session, per cell in order."""
    states: dict[str, list[Any]] = defaultdict(list)
    reports: dict[str, list[Any]] = defaultdict(list)
    for m in logged:
        key = topic_key(m.topic)
        if key == STATE_KEY:
            states[cell_of_topic(m.topic)].append(messages.decode(m.type_name, m.data, m.topic))
        elif key == FOLD_REPORT_KEY:
            reports[cell_of_topic(m.topic)].append(messages.decode(m.type_name, m.data, m.topic))
    rows: list[FoldRow] = []
    for cell, cell_states in sorted(states.items()):
        garments = split_garments(t for st in cell_states for t in transitions_of(st.history))
        starts = [g.start_ns for g in garments if g.start_ns is not None]
        t0 = min(starts) if starts else 0
        for i, garment in enumerate(garments):
            until = garments[i + 1].start_ns if i + 1 < len(garments) else None
            within = [st for st in cell_states
                      if st.garment and _between(st.header.stamp, garment.start_ns, until)]
            if within and within[-1].fold_index:
                garment = garment.renumbered(int(within[-1].fold_index))
            name = within[0].garment if within else ""
            in_garment = [r for r in reports[cell] if _between(r.header.stamp, garment.start_ns, until)]
            for f in garment.folds:
                if f.start_ns is None:
                    continue
                report = next((r for r in reversed(in_garment) if int(r.fold_index) == f.fold), None)
                steps = {s: f.stages_ns.get(s, 0) / 1e9 for s in STEP_STATES}
                steps["other"] = sum(ns for s, ns in f.stages_ns.items() if s not in STEP_STATES) / 1e9
                # the fold's report says more than the transitions (imperfect, and why); a fold that
                # failed was not verified, so it has no IoU
                outcome = None if report is None else FoldOutcome.of_wire(report.outcome)
                verified = report is not None and outcome is not FoldOutcome.FAILED
                rows.append(FoldRow(
                    cell, name, f.fold, (f.start_ns - t0) / 1e9,
                    None if f.end_ns is None else (f.end_ns - f.start_ns) / 1e9,
                    _fold_outcome(report) if report is not None and report.outcome
                    else f.outcome or "in work",
                    steps, None if report is None else int(report.attempt),
                    float(report.verify_iou) if verified and report is not None else None,
                    None if report is None else float(report.robot_time)))
    return rows


def _fold_outcome(report: Any) -> str:
    """`imperfect: <cause>`: a fold report's outcome with its cause, in an operator's words."""
    cause = getattr(report, "cause", "")
    return f"{report.outcome}: {cause}" if cause else str(report.outcome)


def _between(stamp: Any, start_ns: int | None, end_ns: int | None) -> bool:
    ns = messages.stamp_to_ns(stamp)
    return (start_ns is None or ns >= start_ns) and (end_ns is None or ns < end_ns)


def _fold_table(rows: Sequence[FoldRow]) -> str:
    if not rows:
        return '<p class="empty">No fold was logged (no cell/state transitions).</p>'
    many_cells = len({r.cell for r in rows}) > 1
    head = (["cell"] if many_cells else []) + ["garment", "fold", "start (s)", "outcome",
                                               *STEP_STATES, "paused/fault", "total (s)", "attempt",
                                               "verify IoU", "robot time (s)"]

    def num(v: float | None, digits: int = 2) -> str:
        return _shown(v, digits, missing="")

    body = []
    for r in rows:
        cells = ([r.cell] if many_cells else []) + [
            r.garment, str(r.fold), num(r.start_s), r.outcome, *(num(r.steps_s[s]) for s in STEP_STATES),
            num(r.steps_s["other"]), num(r.seconds), "" if r.attempt is None else str(r.attempt),
            num(r.verify_iou, 3), num(r.robot_time_s)]
        body.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    return ('<table class="folds"><tr>' + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
            + "".join(body) + "</table>")


def decimated(count: int, most: int = PLOT_MAX_POINTS) -> range:
    """The indices of `count` samples kept to draw at most `most` of them: every k-th from the first."""
    return range(0, count, max(1, math.ceil(count / most)))


@dataclass(frozen=True)
class JointSeries:
    """One joint-state topic's samples: joint name -> (s since `start_ns`, position (rad)), decimated."""

    start_ns: int
    joints: dict[str, list[tuple[float, float]]]


def joint_series(logged: Iterable[LoggedMessage]) -> dict[str, JointSeries]:
    """Per joint-state topic its decimated samples (only the samples kept are decoded)."""
    by_topic: dict[str, list[LoggedMessage]] = defaultdict(list)
    for m in logged:
        if topic_key(m.topic) == JOINTS_KEY:
            by_topic[m.topic].append(m)
    out: dict[str, JointSeries] = {}
    for topic, samples in sorted(by_topic.items()):
        series: dict[str, list[tuple[float, float]]] = {}
        t0 = samples[0].log_time_ns
        for i in decimated(len(samples)):
            m = samples[i]
            js = messages.decode(m.type_name, m.data, m.topic)
            for name, position in zip(js.name, js.position, strict=False):
                series.setdefault(name, []).append(((m.log_time_ns - t0) / 1e9, float(position)))
        out[topic] = JointSeries(t0, series)
    return out


def garment_starts(logged: Iterable[LoggedMessage]) -> list[tuple[int, str]]:
    """(ns, category) of each garment the cell took up, from its state's garment field changing."""
    starts: list[tuple[int, str]] = []
    current = ""
    for m in logged:
        if topic_key(m.topic) != STATE_KEY:
            continue
        state = messages.decode(m.type_name, m.data, m.topic)
        if state.garment and state.garment != current:
            starts.append((messages.stamp_to_ns(state.header.stamp), state.garment))
        current = state.garment
    return starts


def nice_ticks(lo: float, hi: float, most: int = PLOT_Y_TICKS) -> list[float]:
    """Round values (1, 2 or 5 times a power of ten apart) within [lo, hi], about `most` of them."""
    span = hi - lo
    step = 10.0 ** math.floor(math.log10(span / most))
    step = next(step * k for k in (1, 2, 5, 10) if span / (step * k) <= most)
    first = math.ceil(lo / step - 1e-9)
    return [round(k * step, 10) for k in range(first, math.floor(hi / step + 1e-9) + 1)]


def joint_plot_svg(series: dict[str, list[tuple[float, float]]], marks: Sequence[tuple[float, str]] = (),
                   title: str = "") -> str:
    """An inline SVG: one polyline per joint (`data-joint` names it), position (rad) over time (s), a
    grid at round values, and a dashed line per mark (a garment taken up) labelled with its text."""
    width, height = PLOT_SIZE_PX
    left, top, right, bottom = PLOT_MARGIN_PX
    points = [p for samples in series.values() for p in samples]
    if not points:
        return ""
    t_max = max(t for t, _ in points) or 1.0
    lo, hi = min(v for _, v in points), max(v for _, v in points)
    if hi - lo < 1e-9:
        lo, hi = lo - 1.0, hi + 1.0
    plot_w, plot_h = width - left - right, height - top - bottom

    def x_of(t: float) -> float:
        return left + t / t_max * plot_w

    def y_of(v: float) -> float:
        return top + (hi - v) / (hi - lo) * plot_h

    def xy(t: float, v: float) -> str:
        return f"{x_of(t):.1f},{y_of(v):.1f}"

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
             f'<rect x="{left}" y="{top}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#999"/>',
             f'<text x="{left}" y="{top - 6}" font-weight="bold">{html.escape(title)}</text>',
             f'<text x="{left + plot_w}" y="{height - 2}" text-anchor="end">time (s)</text>',
             f'<text x="14" y="{top + plot_h / 2}" transform="rotate(-90 14 {top + plot_h / 2})" '
             'text-anchor="middle">position (rad)</text>']
    for value in nice_ticks(lo, hi):
        y = y_of(value)
        parts.append(f'<line class="tick" x1="{left}" y1="{y:.1f}" x2="{left + plot_w}" y2="{y:.1f}" '
                     f'stroke="#e4e4e4"/>'
                     f'<text class="position" x="{left - 4}" y="{y + 4:.1f}" '
                     f'text-anchor="end">{value:g}</text>')
    for t in nice_ticks(0.0, t_max, PLOT_X_TICKS):
        x = x_of(t)
        parts.append(f'<line class="tick" x1="{x:.1f}" y1="{top}" x2="{x:.1f}" y2="{top + plot_h}" '
                     f'stroke="#f0f0f0"/>'
                     f'<text class="time" x="{x:.1f}" y="{top + plot_h + 14}" '
                     f'text-anchor="middle">{t:g}</text>')
    for t, text in marks:
        if 0 <= t <= t_max:
            x = x_of(t)
            parts.append(f'<line class="mark" x1="{x:.1f}" y1="{top}" x2="{x:.1f}" y2="{top + plot_h}" '
                         f'stroke="#555" stroke-dasharray="4 3"/>'
                         f'<text x="{x + 3:.1f}" y="{top + 11}">{html.escape(text)}</text>')
    for i, (name, samples) in enumerate(series.items()):
        colour = PLOT_COLOURS[i % len(PLOT_COLOURS)]
        dash = ' stroke-dasharray="6 3"' if i >= len(PLOT_COLOURS) else ""
        parts.append(f'<polyline data-joint="{html.escape(name)}" fill="none" stroke="{colour}"{dash} '
                     f'stroke-width="1.2" points="{" ".join(xy(t, v) for t, v in samples)}"/>')
        y = top + 10 + i * 13
        parts.append(f'<line x1="{width - right + 8}" y1="{y - 4}" x2="{width - right + 28}" y2="{y - 4}" '
                     f'stroke="{colour}"{dash} stroke-width="2"/>'
                     f'<text x="{width - right + 32}" y="{y}">{html.escape(name)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def _joint_plots(topics: dict[str, JointSeries], garments: Sequence[tuple[int, str]]) -> str:
    """Per joint-state topic, a plot per control group (an arm, the turn-table), with each garment's
    start marked: a handful of lines each, told apart by colour."""
    robot = default_robot_config()
    out = []
    for topic, js in topics.items():
        marks = [((ns - js.start_ns) / 1e9, name) for ns, name in garments]
        out.append(f"<h3>{html.escape(topic)}</h3>")
        grouped = [(g.name, {j: js.joints[j] for j in g.joints if j in js.joints}) for g in robot.groups]
        others = {j: v for j, v in js.joints.items() if not any(j in g for _, g in grouped)}
        for name, joints in [*grouped, ("other joints", others)]:
            if joints:
                out.append(joint_plot_svg(joints, marks, f"{name} ({len(joints)} joints)"))
    return "".join(out)


def look_numbers(looks: Sequence[tuple[str, str, int]]) -> list[int]:
    """For each perception, given as (cell, category, folds done), how many times that garment was seen
    after that many folds so far: a retry or another view is look 2, 3, ..., not a copy of the first. A
    garment of the category seen after fewer folds than before is the next garment."""
    counts: dict[tuple[str, str, int], int] = {}
    numbers = []
    for look in looks:
        if any(k[:2] == look[:2] and k[2] > look[2] for k in counts):
            counts = {k: v for k, v in counts.items() if k[:2] != look[:2]}
        counts[look] = counts.get(look, 0) + 1
        numbers.append(counts[look])
    return numbers


def _shown(value: Any, digits: int, missing: str = "-") -> str:
    """A figure for a table cell: `missing` when there is none."""
    return missing if value is None else f"{value:.{digits}f}"


def headline(garments: Sequence[dict]) -> str:
    """`3 of 4 garments folded`, then each garment's verdict in words."""
    done = [g for g in garments if g["outcome"] == "done"]
    imperfect = sum(1 for g in done if g["folds_imperfect"])
    verdicts = []
    for g in garments:
        folds = g["folds_done"]   # imperfect ones among them
        counted = f"{folds} fold{'s' if folds != 1 else ''}" + (
            f", {g['folds_imperfect']} of them imperfect" if g["folds_imperfect"] else "")
        why = f": {g['reason']}" if g["outcome"] != "done" and g["reason"] else ""
        verdicts.append(f"<li><b>{html.escape(g['garment'])}</b> {html.escape(g['outcome'])} "
                        f"({counted}){html.escape(why)}</li>")
    some_imperfect = f" ({imperfect} with imperfect folds)" if imperfect else ""
    return (f'<p class="headline">{len(done)} of {len(garments)} garment{"s" if len(garments) != 1 else ""} '
            f"folded{some_imperfect}</p><ul>{''.join(verdicts)}</ul>")


def write_report(session: Path, summary: dict, out: Path) -> None:
    rows = []
    for g in summary["garments"]:
        measure = g.get("fold_success")
        measured = ("-" if measure is None else "success" if measure["success"]
                    else f"{measure['cause']}: {measure['detail']}")
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (
            g["garment"], g["outcome"], g["folds_done"], _shown(g["final_iou"], 3), measured,
            _shown(g["landmark_error_cm"]["median"], 2), f"{sum(g['compute_s'].values()):.2f}",
            _shown(g["robot_time_s"], 1), _shown(g["wall_time_s"], 1), g["reason"],
            "; ".join(g.get("notes", ())))) + "</tr>")
    files = find_session(session).files
    folds = _fold_table(fold_rows(iter_messages(files)))
    plots = _joint_plots(joint_series(iter_messages(files)), garment_starts(iter_messages(files)))
    figures = []
    seen = [(step, step.observation) for step in logged_perceptions(iter_messages(files))
            if step.observation is not None]
    numbers = look_numbers([(step.cell, obs.category, int(obs.fold_index)) for step, obs in seen])
    for (step, obs), look in zip(seen, numbers, strict=True):
        png = step.image.data.tobytes()
        again = f" (look {look})" if look > 1 else ""
        caption = (f"{html.escape(obs.category)}: after {obs.fold_index} fold(s){again}, "
                   f"matching cost {obs.cost:.1f}; "
                   + ", ".join(f"{t.stage} {t.seconds * 1e3:.0f} ms" for t in obs.timings))
        figures.append(f'<figure><img src="{_data_uri(overlay(png, obs))}" width="{REPORT_WIDTH}">'
                       f"<figcaption>{caption}</figcaption></figure>")
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>foldcell demo report</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
.headline{{font-size:140%;font-weight:bold}}
td,th{{border:1px solid #bbb;padding:4px 8px}} figure{{display:inline-block;margin:8px;vertical-align:top}}
figcaption{{max-width:{REPORT_WIDTH}px;font-size:90%}}</style></head><body>
<h1>foldcell demo</h1>
<section id="garments">
{headline(summary['garments'])}
<p>Time scale {summary['time_scale']:g} (robot time runs that much faster than wall time);
seed {summary['seed']}; session log <code>{html.escape(summary['session_log'])}</code>.</p>
<table class="garments"><tr><th>garment</th><th>outcome</th><th>folds</th><th>final IoU</th>
<th>fold success</th><th>landmark error (cm, median)</th><th>compute (s)</th><th>robot time (s)</th>
<th>wall time (s)</th><th>reason</th><th>notes</th></tr>
{''.join(rows)}</table>
</section>
<section id="folds">
<h2>Every fold</h2>
<p>Time in each step of each fold (s), from the cell's state transitions; attempt, verify IoU and robot
time from the fold's report.</p>
{folds}
</section>
<section id="joints">
<h2>Joint trajectories</h2>
{plots or '<p class="empty">No joint states were recorded.</p>'}
</section>
<section id="perceptions">
<h2>Every perception, with its matched model</h2>
{''.join(figures) or '<p class="empty">No perception was recorded.</p>'}
</section>
</body></html>
"""
    out.write_text(page)
