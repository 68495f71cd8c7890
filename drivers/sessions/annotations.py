"""A `perception/observation` drawn for Foxglove's image panel (`foxglove_msgs/ImageAnnotations`): the
matched polygon, the named landmarks and the category, in image pixels. One builder for the cell's
`perception/annotations` and the Foxglove bridge and export."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.common.configfile import Fields, config_dir, load_yaml
from drivers.wire import messages

ANNOTATIONS_TYPE = "foxglove_msgs/msg/ImageAnnotations"
STYLE_FIELDS = frozenset({"polygon_rgba", "landmark_rgba", "text_rgba", "text_background_rgba",
                          "line_thickness_px", "landmark_diameter_px", "font_size_px"})


@dataclass(frozen=True)
class AnnotationStyle:
    """Colours (r, g, b, a in 0..1) and sizes (image pixels) of the drawing."""

    polygon_rgba: tuple[float, ...]
    landmark_rgba: tuple[float, ...]
    text_rgba: tuple[float, ...]
    text_background_rgba: tuple[float, ...]
    line_thickness_px: float
    landmark_diameter_px: float
    font_size_px: float


def load_annotation_style(path: str | Path | None = None) -> AnnotationStyle:
    """The style of `config/replay_monitor.yaml`'s `foxglove:` section (or of `path`)."""
    f = load_yaml(Path(path) if path else config_dir() / "replay_monitor.yaml").sub("foxglove")
    return annotation_style_from_fields(f)


def annotation_style_from_fields(f: Fields) -> AnnotationStyle:
    """The style keys of a mapping (the `foxglove:` section of config/replay_monitor.yaml)."""
    return AnnotationStyle(
        polygon_rgba=f.floats("polygon_rgba", length=4),
        landmark_rgba=f.floats("landmark_rgba", length=4),
        text_rgba=f.floats("text_rgba", length=4),
        text_background_rgba=f.floats("text_background_rgba", length=4),
        line_thickness_px=f.float("line_thickness_px", positive=True),
        landmark_diameter_px=f.float("landmark_diameter_px", positive=True),
        font_size_px=f.float("font_size_px", positive=True),
    )


def _color(rgba: tuple[float, ...]) -> Any:
    return messages.new("foxglove_msgs/msg/Color", r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def annotations_from_observation(obs: Any, style: AnnotationStyle) -> Any:
    """The matched polygon (a closed line) and the named landmarks (circles, labels) of an observation,
    in image pixels, stamped like the image they were found in."""
    stamp = obs.header.stamp
    point = lambda x, y: messages.new("foxglove_msgs/msg/Point2", x=float(x), y=float(y))  # noqa: E731
    polygon = messages.new(
        "foxglove_msgs/msg/PointsAnnotation",
        timestamp=stamp,
        type=2,
        points=[point(p.x, p.y) for p in obs.polygon_px],  # LINE_LOOP
        outline_color=_color(style.polygon_rgba),
        thickness=style.line_thickness_px,
    )
    circles = [
        messages.new(
            "foxglove_msgs/msg/CircleAnnotation",
            timestamp=stamp,
            position=point(lm.x_px, lm.y_px),
            diameter=style.landmark_diameter_px,
            thickness=style.line_thickness_px,
            fill_color=_color(style.landmark_rgba),
            outline_color=_color(style.landmark_rgba),
        )
        for lm in obs.landmarks
    ]
    offset = style.landmark_diameter_px
    texts = [
        messages.new(
            "foxglove_msgs/msg/TextAnnotation",
            timestamp=stamp,
            position=point(lm.x_px + offset, lm.y_px - offset),
            text=lm.name,
            font_size=style.font_size_px,
            text_color=_color(style.text_rgba),
            background_color=_color(style.text_background_rgba),
        )
        for lm in obs.landmarks
    ]
    if obs.category:
        first = obs.polygon_px[0] if len(obs.polygon_px) else None
        texts.append(
            messages.new(
                "foxglove_msgs/msg/TextAnnotation",
                timestamp=stamp,
                position=point(first.x if first else 0.0, first.y if first else 0.0),
                text=f"{obs.category} (cost {obs.cost:.2f})",
                font_size=style.font_size_px,
                text_color=_color(style.text_rgba),
                background_color=_color(style.text_background_rgba),
            )
        )
    points = [polygon] if len(obs.polygon_px) else []
    return messages.new(ANNOTATIONS_TYPE, circles=circles, points=points, texts=texts)
