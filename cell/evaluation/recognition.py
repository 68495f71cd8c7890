"""Category recognition scored against a CloPeMa-format dataset (`foldcell eval --recognise`).

Every annotated image is perceived with the category not given; the recognised category is
compared with the annotated one in a confusion matrix. A folded garment counts under
"<category> (folded)" and is right when recognised as its category; folded images with a longer
fold history than the recogniser learned from (`recognition.max_folds`) are skipped, as it leaves
them out of learning (folded again and again, any garment becomes a rectangle).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from numpy.typing import NDArray

from cell.perception.annotations import Annotation
from cell.perception.config import PerceptionConfig
from cell.perception.errors import ImageError, PerceptionError
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import perceive
from cell.perception.recognition import Recogniser
from cell.perception.recognition_learning import fold_count
from cell.perception.table_model import TableModel

log = logging.getLogger(__name__)

FAILED = "failed"                    # the confusion matrix's column for images perception failed on


@dataclass(frozen=True)
class RecognisedImage:
    file: str
    truth: str                       # the category, "<category> (folded)" for a folded garment
    recognised: str                  # a category, or FAILED
    confidence: float | None
    error: str | None = None


@dataclass(frozen=True)
class RecognitionReport:
    categories: tuple[str, ...]      # the columns: the models' categories, then FAILED
    confusion: dict[str, dict[str, int]]   # truth -> recognised -> images
    images: list[RecognisedImage]
    skipped_folded: int              # folded more often than the recogniser learned
    unreadable: list[str]

    @property
    def correct(self) -> int:
        return sum(1 for image in self.images if image.recognised == truth_category(image.truth))

    @property
    def accuracy(self) -> float:
        return self.correct / len(self.images) if self.images else float("nan")

    def to_dict(self) -> dict:
        return {"accuracy": self.accuracy, "images": len(self.images), "correct": self.correct,
                "columns": list(self.categories), "confusion": self.confusion,
                "skipped_folded": self.skipped_folded, "unreadable": self.unreadable,
                "per_image": [{"file": i.file, "truth": i.truth, "recognised": i.recognised,
                               "confidence": i.confidence, **({"error": i.error} if i.error else {})}
                              for i in self.images]}


def truth_category(truth: str) -> str:
    """The category a confusion-matrix row should be recognised as."""
    return truth.removesuffix(" (folded)")


def evaluate_recognition(dataset: Iterable[tuple[Path, Annotation]], load_image: Callable[[Path], NDArray],
                         table_model: TableModel, models: Mapping[str, PolygonalModel],
                         config: PerceptionConfig,
                         recogniser: Recogniser | None = None) -> RecognitionReport:
    """Perceive every annotated image with the category not given (`recogniser`, default the
    configured one) and count what it is called. An image that raises `ImageError` in
    `load_image` is listed as unreadable and the evaluation goes on."""
    columns = (*models, FAILED)
    confusion: dict[str, dict[str, int]] = {}
    images: list[RecognisedImage] = []
    unreadable: list[str] = []
    skipped = 0
    for path, annotation in dataset:
        folds = fold_count(annotation)
        if folds is not None and folds > config.recognition.max_folds:
            skipped += 1
            continue
        truth = annotation.category if annotation.shape != "folded" else f"{annotation.category} (folded)"
        try:
            image = load_image(path.parent / annotation.image)
        except ImageError as exc:
            log.warning("%s: %s", path, exc)
            unreadable.append(path.name)
            continue
        row = confusion.setdefault(truth, dict.fromkeys(columns, 0))
        try:
            observation = perceive(image, table_model, models, config, recogniser=recogniser)
        except PerceptionError as exc:
            row[FAILED] += 1
            images.append(RecognisedImage(path.name, truth, FAILED, None, str(exc)))
            continue
        row[observation.category] += 1
        images.append(RecognisedImage(path.name, truth, observation.category, observation.confidence))
    return RecognitionReport(columns, dict(sorted(confusion.items())), images, skipped, unreadable)


def confusion_table(report: RecognitionReport) -> list[str]:
    """The confusion matrix as text lines: a row per annotated category, a column per recognised one."""
    width = max([len(c) for c in report.categories] + [len(t) for t in report.confusion] + [22])
    lines = [f"{'annotated / recognised':{width + 2}s}" + " ".join(f"{c:>{max(len(c), 5)}s}"
                                                                  for c in report.categories)
             + "  recall"]
    for truth, row in report.confusion.items():
        total = sum(row.values())
        right = row.get(truth_category(truth), 0)
        cells = " ".join(f"{row[c]:>{max(len(c), 5)}d}" for c in report.categories)
        lines.append(f"{truth:{width + 2}s}{cells}  {right}/{total}")
    lines.append(f"accuracy {report.accuracy:.1%} ({report.correct} of {len(report.images)} images)")
    return lines
