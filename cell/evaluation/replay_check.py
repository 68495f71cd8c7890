"""Perception again on a logged session's images, against what was logged (`foldcell replay --perceive`).

Nothing is published: each logged `camera/image` (within the selection) is perceived with the current
code and configuration and paired with the logged `perception/observation` carrying its stamp. Each
image is matched with the model the cell matched it with: the category's model before the first fold,
after fold k the folded model derived as the cell derives it (`cell.fold_check.expect_fold`), from the
garment as last matched before fold k and the recipe's fold k; the fold comes from the observation's
`fold_index` (folds done before the image).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cell.evaluation.dataset import landmark_errors
from cell.perception.config import load_perception_config
from cell.perception.errors import ModelError
from cell.perception.folded import derive_folded_model
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import Observation, load_garment_models, load_table_model, perceive
from cell.planning.folds import FoldSpec, Recipe, fold_moves, load_recipe
from drivers.common.garments import LANDMARKS
from drivers.sessions.replay import NS, Selection, Session, select
from drivers.sessions.report import image_stamp_ns, logged_perceptions

# (bgr image, category or None, the model to match or None for the category's) -> what perception makes of it
PerceiveImage = Callable[[np.ndarray, str | None, PolygonalModel | None], Observation]
MIN_HOMOGRAPHY_POINTS = 4


@dataclass(frozen=True)
class _Matched:
    observation: Any  # a logged GarmentObservation
    model: PolygonalModel  # the model it was matched with


class CellModels:
    """The model the cell matched each logged observation with, fed the observations in log order."""

    def __init__(self, models: Mapping[str, PolygonalModel], merge_fraction: float,
                 recipe: Callable[[str], Recipe] = load_recipe):
        self.models = dict(models)
        self.merge_fraction = merge_fraction
        self.recipe = recipe
        self.latest: dict[tuple[str, str, int], _Matched] = {}  # (cell, category, folds done) -> last

    def model_for(self, cell: str, observation: Any) -> PolygonalModel | None:
        """The model of `observation` (None for a category without one). Raises ModelError when no
        observation before its fold was logged to derive the folded model from."""
        category, folds_done = observation.category, int(observation.fold_index)
        model = self.models.get(category)
        if model is None:
            return None
        if folds_done > 0:
            before = self.latest.get((cell, category, folds_done - 1))
            if before is None:
                raise ModelError(f"no {category} image logged before fold {folds_done}: its folded model "
                                 "cannot be derived")
            spec = self.recipe(category).folds[folds_done - 1]
            model = folded_model_after(before.model, before.observation, spec, folds_done,
                                       self.merge_fraction)
        self.latest[(cell, category, folds_done)] = _Matched(observation, model)
        return model


def folded_model_after(model: PolygonalModel, before: Any, spec: FoldSpec, fold_index: int,
                       merge_fraction: float) -> PolygonalModel:
    """The folded model after fold `fold_index` (1-based, `spec` of the recipe) of the garment as the
    logged observation `before` matched it with `model`. The grasp and place points go to pixels by the
    homography of the observation's own landmarks (their table coordinates are their pixels through the
    camera's table homography, so it is exact)."""
    pixels = {lm.name: (float(lm.x_px), float(lm.y_px)) for lm in before.landmarks}
    table = {lm.name: (float(lm.x_table), float(lm.y_table)) for lm in before.landmarks}
    if set(pixels) != set(model.names):
        raise ModelError(f"the observation before fold {fold_index} names {sorted(pixels)}, its model "
                         f"{sorted(model.names)}")
    if len(pixels) < MIN_HOMOGRAPHY_POINTS:
        raise ModelError(f"the observation before fold {fold_index} has {len(pixels)} landmarks: "
                         f"{MIN_HOMOGRAPHY_POINTS} are needed to place the fold in the image")
    names = list(model.names)
    matched_px = np.array([pixels[n] for n in names])
    homography, _ = cv2.findHomography(np.array([table[n] for n in names]), matched_px)
    if homography is None:
        raise ModelError(f"the landmarks before fold {fold_index} give no table-to-image homography")
    grasp, place = fold_moves(table, spec)
    move_px = cv2.perspectiveTransform(np.array([[grasp[0], place[0]]], dtype=float), homography)[0]
    return derive_folded_model(model, matched_px, (move_px[0], move_px[1]), fold_index, merge_fraction)


@dataclass(frozen=True)
class ImageComparison:
    """One logged image: the landmarks logged then, the ones perception finds now, their distance."""

    topic: str
    stamp_ns: int
    log_time_s: float  # seconds into the session
    logged_category: str | None
    new_category: str | None
    folds_done: int | None  # before the image, as logged: which model it was matched with
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
            "folds_done": self.folds_done,
            "logged": {k: [round(x, 2), round(y, 2)] for k, (x, y) in self.logged.items()},
            "new": {k: [round(x, 2), round(y, 2)] for k, (x, y) in self.new.items()},
            "difference_px": {k: round(v, 2) for k, v in d.items()},
            "max_difference_px": round(max(d.values()), 2) if d else None,
            "unpaired": sorted(set(self.logged) ^ set(self.new)),  # landmarks only one side has
            "error": self.error,
        }


def compare_session(
    session: Session,
    selection: Selection,
    perceive_image: PerceiveImage | None = None,
    models: CellModels | None = None,
) -> list[ImageComparison]:
    """Perception again on every logged image of the selection, against the logged observation.

    An image is paired with the logged observation of the same cell carrying its stamp and matched
    with the model the cell used (`models`, default from the configured garment models).
    `perceive_image(bgr, category, model) -> Observation` defaults to `cell.perception.pipeline.perceive`
    with the configured table model.
    """
    config = load_perception_config()
    if perceive_image is None:
        perceive_image = _default_perceiver()
    if models is None:
        models = CellModels(load_garment_models(config), config.merge_fraction)
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
            model = models.model_for(step.cell, obs) if obs is not None and category else None
            result = perceive_image(_decode_image(step.image.data), category, model)
            new_cat = result.category
            new_lm = {k: (float(v[0]), float(v[1])) for k, v in result.landmarks.items()}
        except Exception as exc:  # a failed image is reported and the others still run
            error = f"{type(exc).__name__}: {exc}"
        out.append(ImageComparison(step.message.topic, image_stamp_ns(step.message, step.image),
                                   (step.message.log_time_ns - session.start_ns) / NS, category, new_cat,
                                   int(obs.fold_index) if obs is not None else None, logged_lm, new_lm,
                                   error))
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

    def perceive_image(bgr: np.ndarray, category: str | None, model: PolygonalModel | None) -> Observation:
        if category is not None and model is not None:
            return perceive(bgr, table, {category: model}, cfg, category)
        return perceive(bgr, table, models, cfg, category if category in models else None)

    return perceive_image


def format_comparison(c: ImageComparison) -> str:
    """Text for one image: a header line, then one line per landmark (logged, new, difference)."""
    head = (
        f"{c.log_time_s:8.3f} s  {c.topic}  stamp {c.stamp_ns}  "
        f"logged {c.logged_category or '-'}  new {c.new_category or '-'}"
        + (f"  after {c.folds_done} fold(s)" if c.folds_done else "")
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
