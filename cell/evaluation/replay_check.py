"""Perception again on a logged session's images, against what was logged (`foldcell replay --perceive`).

Nothing is published: each logged `camera/image` (within the selection) is perceived with the current
code and configuration and paired with the logged `perception/observation` carrying its stamp.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from cell.evaluation.dataset import landmark_errors
from cell.perception.config import load_perception_config
from cell.perception.pipeline import Observation, load_garment_models, load_table_model, perceive
from drivers.common.garments import LANDMARKS
from drivers.sessions.replay import NS, Selection, Session, select
from drivers.sessions.report import image_stamp_ns, logged_perceptions

# (bgr image, category or None) -> the observation perception makes of it
PerceiveImage = Callable[[np.ndarray, str | None], Observation]


@dataclass(frozen=True)
class ImageComparison:
    """One logged image: the landmarks logged then, the ones perception finds now, their distance."""

    topic: str
    stamp_ns: int
    log_time_s: float  # seconds into the session
    logged_category: str | None
    new_category: str | None
    logged: dict[str, tuple[float, float]]
    new: dict[str, tuple[float, float]]
    error: str | None = None  # perception failed on this image

    @property
    def distances_px(self) -> dict[str, float]:
        """Distance of each landmark to the logged one; a towel's under the better of its namings
        (its turns look the same, so either run may name a different corner first)."""
        category = self.new_category or ""
        order = LANDMARKS.get(category, ())
        if order and set(order) == set(self.new) == set(self.logged):
            errors, _ = landmark_errors(self.new, self.logged, order, category, facing_known=True)
            return dict(zip(order, errors.tolist(), strict=True))
        return {
            n: float(((self.logged[n][0] - p[0]) ** 2 + (self.logged[n][1] - p[1]) ** 2) ** 0.5)
            for n, p in self.new.items()
            if n in self.logged
        }

    def to_json(self) -> dict:
        d = self.distances_px
        return {
            "topic": self.topic,
            "stamp_ns": self.stamp_ns,
            "time_s": round(self.log_time_s, 3),
            "logged_category": self.logged_category,
            "new_category": self.new_category,
            "logged": {k: [round(x, 2), round(y, 2)] for k, (x, y) in self.logged.items()},
            "new": {k: [round(x, 2), round(y, 2)] for k, (x, y) in self.new.items()},
            "difference_px": {k: round(v, 2) for k, v in d.items()},
            "max_difference_px": round(max(d.values()), 2) if d else None,
            "error": self.error,
        }


def compare_session(
    session: Session,
    selection: Selection,
    perceive_image: PerceiveImage | None = None,
) -> list[ImageComparison]:
    """Perception again on every logged image of the selection, against the logged observation.

    An image is paired with the logged observation of the same cell carrying its stamp.
    `perceive_image(bgr, category) -> Observation` defaults to `cell.perception.pipeline.perceive`
    with the configured table and garment models.
    """
    if perceive_image is None:
        perceive_image = _default_perceiver()
    out: list[ImageComparison] = []
    for step in logged_perceptions(select(session, selection)):
        obs = step.observation
        logged_lm = ({lm.name: (float(lm.x_px), float(lm.y_px)) for lm in obs.landmarks}
                     if obs is not None else {})
        category = obs.category if obs is not None and obs.category else None
        new_cat: str | None = None
        new_lm: dict[str, tuple[float, float]] = {}
        error: str | None = None
        try:
            result = perceive_image(_decode_image(step.image.data), category)
            new_cat = result.category
            new_lm = {k: (float(v[0]), float(v[1])) for k, v in result.landmarks.items()}
        except Exception as exc:  # a failed image is reported and the others still run
            error = f"{type(exc).__name__}: {exc}"
        out.append(ImageComparison(step.message.topic, image_stamp_ns(step.message, step.image),
                                   (step.message.log_time_ns - session.start_ns) / NS, category, new_cat,
                                   logged_lm, new_lm, error))
    return out


def _decode_image(data: np.ndarray) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data.tobytes(), np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise ValueError("the logged image does not decode")
    return img


def _default_perceiver() -> PerceiveImage:
    cfg = load_perception_config()
    table = load_table_model(None, cfg)
    models = load_garment_models(cfg)
    return lambda bgr, category: perceive(bgr, table, models, cfg, category if category in models else None)


def format_comparison(c: ImageComparison) -> str:
    """Text for one image: a header line, then one line per landmark (logged, new, difference)."""
    head = (
        f"{c.log_time_s:8.3f} s  {c.topic}  stamp {c.stamp_ns}  "
        f"logged {c.logged_category or '-'}  new {c.new_category or '-'}"
    )
    if c.error:
        return head + f"\n    perception failed: {c.error}\n"
    lines = [head]
    d = c.distances_px
    for name in list(c.logged) + [n for n in c.new if n not in c.logged]:
        lp, np_ = c.logged.get(name), c.new.get(name)
        lt = f"{lp[0]:8.1f} {lp[1]:8.1f}" if lp else f"{'-':>8} {'-':>8}"
        nt = f"{np_[0]:8.1f} {np_[1]:8.1f}" if np_ else f"{'-':>8} {'-':>8}"
        dt = f"{d[name]:7.1f} px" if name in d else "      -"
        lines.append(f"    {name:20s} logged {lt}   new {nt}   diff {dt}")
    return "\n".join(lines) + "\n"
