"""A session's perceptions, and the demo's HTML report: every perception's image with its matched
model drawn on it, and the summary."""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

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


def overlay(png: bytes, observation: Any) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError("the logged image does not decode")
    pts = np.array([[lm.x_px, lm.y_px] for lm in observation.landmarks], dtype=np.float32)
    if len(pts):
        cv2.polylines(image, [np.round(pts).astype(np.int32)], True, POLYGON_BGR, 4, cv2.LINE_AA)
    for lm in observation.landmarks:
        centre = (round(lm.x_px), round(lm.y_px))
        cv2.circle(image, centre, 9, LANDMARK_BGR, 3, cv2.LINE_AA)
        cv2.putText(image, lm.name, (centre[0] + 12, centre[1] - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.9,
                    LANDMARK_BGR, 2, cv2.LINE_AA)
    scale = REPORT_WIDTH / image.shape[1]
    return cv2.resize(image, (REPORT_WIDTH, int(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)


def _data_uri(image: np.ndarray) -> str:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode() if ok else ""


IMAGE_KEY = "camera/image"
OBSERVATION_KEY = "perception/observation"


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


def write_report(session: Path, summary: dict, out: Path) -> None:
    rows = []
    for g in summary["garments"]:
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (
            g["garment"], g["outcome"], g["folds_done"], g["final_iou"],
            g["landmark_error_cm"]["median"], round(sum(g["compute_s"].values()), 3),
            g["robot_time_s"], g["wall_time_s"], g["reason"], "; ".join(g.get("notes", ())))) + "</tr>")
    figures = []
    for step in logged_perceptions(iter_messages(find_session(session).files)):
        obs, png = step.observation, step.image.data.tobytes()
        if obs is None:
            continue
        caption = (f"{html.escape(obs.category)}: after {obs.fold_index} fold(s), "
                   f"matching cost {obs.cost:.1f}; "
                   + ", ".join(f"{t.stage} {t.seconds * 1e3:.0f} ms" for t in obs.timings))
        figures.append(f'<figure><img src="{_data_uri(overlay(png, obs))}" width="{REPORT_WIDTH}">'
                       f"<figcaption>{caption}</figcaption></figure>")
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>foldcell demo report</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #bbb;padding:4px 8px}} figure{{display:inline-block;margin:8px;vertical-align:top}}
figcaption{{max-width:{REPORT_WIDTH}px;font-size:90%}}</style></head><body>
<h1>foldcell demo</h1>
<p>Time scale {summary['time_scale']:g} (robot time runs that much faster than wall time);
seed {summary['seed']}; session log <code>{html.escape(summary['session_log'])}</code>.</p>
<table><tr><th>garment</th><th>outcome</th><th>folds</th><th>final IoU</th>
<th>landmark error (cm, median)</th><th>compute (s)</th><th>robot time (s)</th><th>wall time (s)</th>
<th>reason</th><th>notes</th></tr>
{''.join(rows)}</table>
<h2>Every perception, with its matched model</h2>
{''.join(figures) or '<p>No perception was recorded.</p>'}
</body></html>
"""
    out.write_text(page)
