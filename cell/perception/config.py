"""Perception parameters from `config/perception.yaml`, as frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_fields, load_yaml, rule

from .matching import MatchWeights


@dataclass(frozen=True)
class SegmentationConfig:
    work_size: tuple[int, int] = rule(min=16, default=(320, 256))
    quantile_fg: float = rule(min=0.0, max=0.5, default=0.03)
    fraction_bg: float = rule(min=0.0, max=1.0, default=0.80)
    grabcut_iterations: int = rule(min=1, max=20, default=3)
    grabcut_converged_fraction: float = rule(min=0.0, max=1.0, default=0.002)
    min_area_fraction: float = rule(min=0.0, max=1.0, default=0.01)
    border_margin_px: int = rule(min=0, max=50, default=2)
    refine_band_px: int = rule(min=0, max=50, default=6)
    garment_var_floor: float = rule(positive=True, default=25.0)
    grabcut_margin_px: int = rule(min=1, max=100, default=12)
    sure_fg_radius_px: int = rule(min=0, max=20, default=1)
    refine_passes: int = rule(min=1, max=20, default=3)
    adapt_light: bool = rule(default=True)
    light_mahalanobis: float = rule(positive=True, default=2.0)
    light_max_log_change: float = rule(positive=True, default=0.7)
    light_min_fraction: float = rule(min=0.0, max=1.0, default=0.1)
    light_grid: tuple[int, int] = rule(min=1, default=(8, 10))
    light_sample_stride: int = rule(min=1, max=16, default=4)
    saturation_level: int = rule(min=1, max=255, default=250)
    glare_chroma_tolerance: float = rule(positive=True, default=0.12)
    glare_mahalanobis: float = rule(positive=True, default=3.0)
    glare_context_px: float = rule(positive=True, default=4.0)
    glare_max_brightness: float = rule(positive=True, default=1.1)
    grabcut_components: int = rule(min=1, max=5, default=3)
    grabcut_sample_stride: int = rule(min=1, max=16, default=3)
    grabcut_var_floor: float = rule(positive=True, default=4.0)
    min_table_blob_fraction: float = rule(min=0.0, max=0.5, default=0.004)
    grabcut_flat_light: bool = rule(default=False)
    spur_radius_px: int = rule(min=0, max=20, default=1)
    open_slits: bool = rule(default=True)
    slit_min_width_px: int = rule(min=0, max=20, default=2)
    slit_mahalanobis: float = rule(positive=True, default=4.0)
    grabcut_keep_fraction: float = rule(min=0.0, max=1.0, default=0.65)
    unknown_table_hue_fixed: bool = rule(default=True)
    core_window_px: int = rule(min=1, max=31, default=7)
    core_density: float = rule(min=0.0, max=1.0, default=0.5)
    grabcut_scale: int = rule(min=1, max=4, default=2)
    grabcut_max_growth: float = rule(min=0.0, max=1.0, default=0.03)


@dataclass(frozen=True)
class TableFitConfig:
    components: int = rule(min=1, max=16, default=3)
    em_iterations: int = rule(min=1, default=100)
    covariance_floor: float = rule(positive=True, default=1.0)
    samples: int = rule(min=100, default=60000)
    gain_grid: tuple[int, int] = rule(min=1, default=(8, 10))
    min_cell_coverage: float = rule(min=0.0, max=1.0, default=0.2)
    # around a flat garment's node polygon
    annotation_margin_px: int = rule(min=0, default=25)
    # around the convex hull of a folded garment's nodes
    folded_margin_px: int = rule(min=0, default=60)
    # EM fits all but this least likely part of the pixels (see `fit_gmm`)
    trim_fraction: float = rule(min=0.0, max=0.5, default=0.0)
    # > 0: fit again without the pixels this far from every component
    outlier_mahalanobis: float = rule(min=0.0, default=0.0)
    # and without a component this light of another hue than the rest
    foreign_weight: float = rule(min=0.0, max=1.0, default=0.1)


@dataclass(frozen=True)
class SimplifyConfig:
    candidate_tolerance_px: float = rule(positive=True, default=1.0)
    max_candidates: int = rule(min=4, max=200, default=40)
    # fraction of the perimeter; see `simplify.with_points_near`
    expected_vertex_gap: float = rule(min=0.0, max=0.5, default=0.02)


@dataclass(frozen=True)
class TableFallbackConfig:
    """When the table model does not describe an image (another table, other light), one is fitted
    to the image's border ring, where a garment that does not touch the border leaves only table."""
    enabled: bool = rule(default=True)
    # ring width, as a fraction of the image's width and height
    border_fraction: float = rule(positive=True, max=0.25, default=0.06)
    # the model fits if at least this part of the ring is not sure garment
    min_table_fraction: float = rule(min=0.0, max=1.0, default=0.5)
    em_iterations: int = rule(min=1, default=10)          # the ring's model: EM iterations at most,
    samples: int = rule(min=100, default=4000)            # ring pixels (work size) it is fitted on,
    # least likely part of them left out (garment near the border)
    trim_fraction: float = rule(min=0.0, max=0.5, default=0.05)
    # > 0: fitted again without outliers (see `TableFitConfig`)
    outlier_mahalanobis: float = rule(min=0.0, default=0.0)
    # doubt: more of the ring than this is garment (it was fitted as table)
    max_ring_garment: float = rule(min=0.0, max=1.0, default=0.01)
    # doubt: more of the table than this is sure garment by it
    max_table_unexplained: float = rule(min=0.0, max=1.0, default=0.08)


@dataclass(frozen=True)
class AugmentConfig:
    """How training outlines of the recogniser are varied (`recognition_learning.augment_contour`);
    ranges are [low, high]."""
    # factor on one end of the outline
    stretch: tuple[float, float] = rule(min=0.1, max=10.0, default=(0.9, 1.8))
    # where the stretch starts, fraction of the extent
    stretch_from: tuple[float, float] = rule(min=0.0, max=1.0, default=(0.0, 0.5))
    # border waves, fraction of sqrt(area)
    wrinkle_amplitude: tuple[float, float] = rule(min=0.0, max=0.2, default=(0.0, 0.012))
    # waves along the whole border
    wrinkle_waves: tuple[int, int] = rule(min=1, max=1000, default=(8, 40))
    fold_probability: float = rule(min=0.0, max=1.0, default=0.15)     # an end folded over
    # the folded-over end, fraction of the extent
    fold_depth: tuple[float, float] = rule(min=0.0, max=0.5, default=(0.15, 0.4))


@dataclass(frozen=True)
class RecognitionConfig:
    """Category recognition when the category is not given: the learned classifier's file, and how
    `foldcell models learn-recognition` learns it."""
    # relative to config/ in the file (given by the loader)
    model: Path = Path("perception/recognition.yaml")
    # varied copies of each training outline, beside the outline itself
    augmentations: int = rule(min=0, max=1000, default=6)
    # folded training images with a longer fold history are left out
    max_folds: int = rule(min=0, default=1)
    regularisation: float = rule(min=0.0, default=1e-3)   # L2 penalty on the classifier's weights
    seed: int = rule(min=0, default=0)                    # of the augmentations
    augment: AugmentConfig = rule(section=True, default=AugmentConfig())  # noqa: RUF009 - a frozen dataclass
    # a recognition less sure than this is in doubt
    unsure_below: float = rule(min=0.0, max=1.0, default=0.8)
    # a matched model's cost above this: the outline is not that garment
    max_fit_cost: float = rule(default=50.0)


@dataclass(frozen=True)
class PerceptionConfig:
    """config/perception.yaml; `merge_fraction` is its `folded` section's, the variance floors its
    `models` section's. The loader gives the paths (relative to config/ in the file), `matching` (other
    names in the file) and `recognition`."""
    table_model: Path = Path("perception/table_gmm.yaml")
    garments_dir: Path = Path("garments")
    segmentation: SegmentationConfig = rule(section=True, default=SegmentationConfig())  # noqa: RUF009 - a frozen dataclass
    table: TableFitConfig = rule(section=True, default=TableFitConfig())  # noqa: RUF009 - a frozen dataclass
    simplify: SimplifyConfig = rule(section=True, default=SimplifyConfig())  # noqa: RUF009 - a frozen dataclass
    matching: MatchWeights = field(default_factory=MatchWeights)
    merge_fraction: float = rule(min=0.0, max=0.5, under="folded", default=0.02)
    angle_var_floor: float = rule(positive=True, under="models", default=0.0076)
    length_var_floor: float = rule(positive=True, under="models", default=2e-5)
    table_fallback: TableFallbackConfig = rule(section=True, default=TableFallbackConfig())  # noqa: RUF009 - a frozen dataclass
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)


def perception_config_from_fields(f: Fields, base: Path) -> PerceptionConfig:
    return load_fields(PerceptionConfig, f, table_model=base / f.str("table_model"),
                       garments_dir=base / f.str("garments_dir"), matching=_matching(f.sub("matching")),
                       recognition=_recognition(f.sub("recognition"), base))


def _matching(fields: Fields) -> MatchWeights:
    fields.reject_unknown({"lambda_vertex", "lambda_edge", "lambda_segment", "straight_mean", "straight_var",
                           "upright_margin", "lambda_position", "position_sigma_fraction"})
    return MatchWeights(fields.float("lambda_vertex", min=0.0), fields.float("lambda_edge", min=0.0),
                        fields.float("lambda_segment", min=0.0), fields.float("straight_mean"),
                        fields.float("straight_var", positive=True), fields.float("upright_margin", min=0.0),
                        fields.float("lambda_position", min=0.0),
                        fields.float("position_sigma_fraction", positive=True))


def _recognition(fields: Fields, base: Path) -> RecognitionConfig:
    config = load_fields(RecognitionConfig, fields, model=base / fields.str("model"))
    augment = config.augment
    for name in ("stretch", "stretch_from", "wrinkle_amplitude", "wrinkle_waves", "fold_depth"):
        low, high = getattr(augment, name)
        if low > high:
            raise fields.sub("augment").error(name, f"must be [low, high] with low <= high, "
                                                    f"got {[low, high]}")
    return config


def load_perception_config(path: str | Path | None = None) -> PerceptionConfig:
    """Load `config/perception.yaml` (or `path`); relative paths in it are against config/."""
    p = Path(path) if path is not None else config_dir() / "perception.yaml"
    return perception_config_from_fields(load_yaml(p), config_dir())
