"""Perception parameters from `config/perception.yaml`, as frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_yaml

from .matching import MatchWeights


@dataclass(frozen=True)
class SegmentationConfig:
    work_size: tuple[int, int] = (320, 256)
    quantile_fg: float = 0.03
    fraction_bg: float = 0.80
    grabcut_iterations: int = 3
    grabcut_converged_fraction: float = 0.002
    min_area_fraction: float = 0.01
    border_margin_px: int = 2
    refine_band_px: int = 6
    garment_var_floor: float = 25.0
    grabcut_margin_px: int = 12
    sure_fg_radius_px: int = 1
    refine_passes: int = 3
    adapt_light: bool = True
    light_mahalanobis: float = 2.0
    light_max_log_change: float = 0.7
    light_min_fraction: float = 0.1
    light_grid: tuple[int, int] = (8, 10)
    light_sample_stride: int = 4
    saturation_level: int = 250
    glare_chroma_tolerance: float = 0.12
    glare_mahalanobis: float = 3.0
    glare_context_px: float = 4.0
    glare_max_brightness: float = 1.1
    grabcut_components: int = 3
    grabcut_sample_stride: int = 3
    grabcut_var_floor: float = 4.0
    min_table_blob_fraction: float = 0.004
    grabcut_flat_light: bool = False
    spur_radius_px: int = 1
    open_slits: bool = True
    slit_min_width_px: int = 2
    slit_mahalanobis: float = 4.0
    grabcut_keep_fraction: float = 0.65
    unknown_table_hue_fixed: bool = True
    core_window_px: int = 7
    core_density: float = 0.5
    grabcut_scale: int = 2
    grabcut_max_growth: float = 0.03


@dataclass(frozen=True)
class TableFitConfig:
    components: int = 3
    em_iterations: int = 100
    covariance_floor: float = 1.0
    samples: int = 60000
    gain_grid: tuple[int, int] = (8, 10)
    min_cell_coverage: float = 0.2
    annotation_margin_px: int = 25    # around a flat garment's node polygon
    folded_margin_px: int = 60        # around the convex hull of a folded garment's nodes
    trim_fraction: float = 0.0        # EM fits all but this least likely part of the pixels (see `fit_gmm`)
    outlier_mahalanobis: float = 0.0  # > 0: fit again without the pixels this far from every component
    foreign_weight: float = 0.1       # and without a component this light of another hue than the rest


@dataclass(frozen=True)
class SimplifyConfig:
    candidate_tolerance_px: float = 1.0
    max_candidates: int = 40
    expected_vertex_gap: float = 0.02   # fraction of the perimeter; see `simplify.with_points_near`


@dataclass(frozen=True)
class TableFallbackConfig:
    """When the table model does not describe an image (another table, other light), one is fitted
    to the image's border ring, where a garment that does not touch the border leaves only table."""
    enabled: bool = True
    border_fraction: float = 0.06     # ring width, as a fraction of the image's width and height
    min_table_fraction: float = 0.5   # the model fits if at least this part of the ring is not sure garment
    em_iterations: int = 10           # the ring's model: EM iterations at most,
    samples: int = 4000               # ring pixels (work size) it is fitted on,
    trim_fraction: float = 0.05       # least likely part of them left out (garment near the border)
    outlier_mahalanobis: float = 0.0  # > 0: fitted again without outliers (see `TableFitConfig`)
    max_ring_garment: float = 0.01    # doubt: more of the ring than this is garment (it was fitted as table)
    max_table_unexplained: float = 0.08  # doubt: more of the table than this is sure garment by it


@dataclass(frozen=True)
class AugmentConfig:
    """How training outlines of the recogniser are varied (`recognition_learning.augment_contour`);
    ranges are [low, high]."""
    stretch: tuple[float, float] = (0.9, 1.8)          # factor on one end of the outline
    stretch_from: tuple[float, float] = (0.0, 0.5)     # where the stretch starts, fraction of the extent
    wrinkle_amplitude: tuple[float, float] = (0.0, 0.012)  # border waves, fraction of sqrt(area)
    wrinkle_waves: tuple[int, int] = (8, 40)           # waves along the whole border
    fold_probability: float = 0.15                     # an end folded over
    fold_depth: tuple[float, float] = (0.15, 0.4)      # the folded-over end, fraction of the extent


@dataclass(frozen=True)
class RecognitionConfig:
    """Category recognition when the category is not given: the learned classifier's file, and how
    `foldcell models learn-recognition` learns it."""
    model: Path = Path("perception/recognition.yaml")
    augmentations: int = 6            # varied copies of each training outline, beside the outline itself
    max_folds: int = 1                # folded training images with a longer fold history are left out
    regularisation: float = 1e-3      # L2 penalty on the classifier's weights
    seed: int = 0                     # of the augmentations
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    unsure_below: float = 0.8         # a recognition less sure than this is in doubt
    max_fit_cost: float = 50.0        # a matched model's cost above this: the outline is not that garment


@dataclass(frozen=True)
class PerceptionConfig:
    table_model: Path = Path("perception/table_gmm.yaml")
    garments_dir: Path = Path("garments")
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    table: TableFitConfig = field(default_factory=TableFitConfig)
    simplify: SimplifyConfig = field(default_factory=SimplifyConfig)
    matching: MatchWeights = field(default_factory=MatchWeights)
    merge_fraction: float = 0.02
    angle_var_floor: float = 0.0076
    length_var_floor: float = 2e-5
    table_fallback: TableFallbackConfig = field(default_factory=TableFallbackConfig)
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)


def _grid(f: Fields, name: str) -> tuple[int, int]:
    grid = f.raw(name)
    if not (isinstance(grid, list) and len(grid) == 2 and all(isinstance(v, int) and v >= 1 for v in grid)):
        raise f.error(name, f"must be [rows, cols] positive integers, got {grid!r}")
    return (grid[0], grid[1])


def perception_config_from_fields(f: Fields, base: Path) -> PerceptionConfig:
    f.reject_unknown({"table_model", "garments_dir", "segmentation", "table", "simplify", "matching",
                      "models", "folded", "table_fallback", "recognition"})
    return PerceptionConfig(base / f.str("table_model"), base / f.str("garments_dir"),
                            _segmentation(f.sub("segmentation")), _table_fit(f.sub("table")),
                            _simplify(f.sub("simplify")), _matching(f.sub("matching")),
                            _folded(f.sub("folded")), *_variance_floors(f.sub("models")),
                            _table_fallback(f.sub("table_fallback")),
                            _recognition(f.sub("recognition"), base))


def _segmentation(fields: Fields) -> SegmentationConfig:
    fields.reject_unknown(set(SegmentationConfig.__dataclass_fields__))
    size = fields.raw("work_size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v >= 16 for v in size)):
        raise fields.error("work_size", f"must be [width, height] integers >= 16, got {size!r}")
    return SegmentationConfig(
        (size[0], size[1]), fields.float("quantile_fg", min=0.0, max=0.5),
        fields.float("fraction_bg", min=0.0, max=1.0), fields.int("grabcut_iterations", min=1, max=20),
        fields.float("grabcut_converged_fraction", min=0.0, max=1.0),
        fields.float("min_area_fraction", min=0.0, max=1.0),
        fields.int("border_margin_px", min=0, max=50), fields.int("refine_band_px", min=0, max=50),
        fields.float("garment_var_floor", positive=True), fields.int("grabcut_margin_px", min=1, max=100),
        fields.int("sure_fg_radius_px", min=0, max=20), fields.int("refine_passes", min=1, max=20),
        fields.bool("adapt_light"), fields.float("light_mahalanobis", positive=True),
        fields.float("light_max_log_change", positive=True),
        fields.float("light_min_fraction", min=0.0, max=1.0), _grid(fields, "light_grid"),
        fields.int("light_sample_stride", min=1, max=16),
        fields.int("saturation_level", min=1, max=255), fields.float("glare_chroma_tolerance", positive=True),
        fields.float("glare_mahalanobis", positive=True),
        fields.float("glare_context_px", positive=True),
        fields.float("glare_max_brightness", positive=True), fields.int("grabcut_components", min=1, max=5),
        fields.int("grabcut_sample_stride", min=1, max=16), fields.float("grabcut_var_floor", positive=True),
        fields.float("min_table_blob_fraction", min=0.0, max=0.5), fields.bool("grabcut_flat_light"),
        fields.int("spur_radius_px", min=0, max=20), fields.bool("open_slits"),
        fields.int("slit_min_width_px", min=0, max=20), fields.float("slit_mahalanobis", positive=True),
        fields.float("grabcut_keep_fraction", min=0.0, max=1.0), fields.bool("unknown_table_hue_fixed"),
        fields.int("core_window_px", min=1, max=31), fields.float("core_density", min=0.0, max=1.0),
        fields.int("grabcut_scale", min=1, max=4),
        fields.float("grabcut_max_growth", min=0.0, max=1.0))


def _table_fit(fields: Fields) -> TableFitConfig:
    fields.reject_unknown(set(TableFitConfig.__dataclass_fields__))
    return TableFitConfig(fields.int("components", min=1, max=16), fields.int("em_iterations", min=1),
                          fields.float("covariance_floor", positive=True), fields.int("samples", min=100),
                          _grid(fields, "gain_grid"), fields.float("min_cell_coverage", min=0.0, max=1.0),
                          fields.int("annotation_margin_px", min=0), fields.int("folded_margin_px", min=0),
                          fields.float("trim_fraction", min=0.0, max=0.5),
                          fields.float("outlier_mahalanobis", min=0.0),
                          fields.float("foreign_weight", min=0.0, max=1.0))


def _simplify(fields: Fields) -> SimplifyConfig:
    fields.reject_unknown(set(SimplifyConfig.__dataclass_fields__))
    return SimplifyConfig(fields.float("candidate_tolerance_px", positive=True),
                          fields.int("max_candidates", min=4, max=200),
                          fields.float("expected_vertex_gap", min=0.0, max=0.5))


def _matching(fields: Fields) -> MatchWeights:
    fields.reject_unknown({"lambda_vertex", "lambda_edge", "lambda_segment", "straight_mean", "straight_var",
                           "upright_margin", "lambda_position", "position_sigma_fraction"})
    return MatchWeights(fields.float("lambda_vertex", min=0.0), fields.float("lambda_edge", min=0.0),
                        fields.float("lambda_segment", min=0.0), fields.float("straight_mean"),
                        fields.float("straight_var", positive=True), fields.float("upright_margin", min=0.0),
                        fields.float("lambda_position", min=0.0),
                        fields.float("position_sigma_fraction", positive=True))


def _folded(fields: Fields) -> float:
    """The merge fraction of folded models."""
    fields.reject_unknown({"merge_fraction"})
    return fields.float("merge_fraction", min=0.0, max=0.5)


def _variance_floors(fields: Fields) -> tuple[float, float]:
    """The learned models' angle and edge-length variance floors."""
    fields.reject_unknown({"angle_var_floor", "length_var_floor"})
    return fields.float("angle_var_floor", positive=True), fields.float("length_var_floor", positive=True)


def _table_fallback(fields: Fields) -> TableFallbackConfig:
    fields.reject_unknown(set(TableFallbackConfig.__dataclass_fields__))
    return TableFallbackConfig(fields.bool("enabled"),
                               fields.float("border_fraction", positive=True, max=0.25),
                               fields.float("min_table_fraction", min=0.0, max=1.0),
                               fields.int("em_iterations", min=1), fields.int("samples", min=100),
                               fields.float("trim_fraction", min=0.0, max=0.5),
                               fields.float("outlier_mahalanobis", min=0.0),
                               fields.float("max_ring_garment", min=0.0, max=1.0),
                               fields.float("max_table_unexplained", min=0.0, max=1.0))


def _range(fields: Fields, name: str, low: float, high: float) -> tuple[float, float]:
    values = fields.floats(name)
    if len(values) != 2 or not low <= values[0] <= values[1] <= high:
        raise fields.error(name, f"must be [low, high] with {low} <= low <= high <= {high}, "
                                 f"got {list(values)}")
    return (values[0], values[1])


def _recognition(fields: Fields, base: Path) -> RecognitionConfig:
    fields.reject_unknown(set(RecognitionConfig.__dataclass_fields__))
    augment = fields.sub("augment")
    augment.reject_unknown(set(AugmentConfig.__dataclass_fields__))
    waves = _range(augment, "wrinkle_waves", 1, 1000)
    return RecognitionConfig(
        base / fields.str("model"), fields.int("augmentations", min=0, max=1000),
        fields.int("max_folds", min=0), fields.float("regularisation", min=0.0), fields.int("seed", min=0),
        AugmentConfig(_range(augment, "stretch", 0.1, 10.0), _range(augment, "stretch_from", 0.0, 1.0),
                      _range(augment, "wrinkle_amplitude", 0.0, 0.2), (int(waves[0]), int(waves[1])),
                      augment.float("fold_probability", min=0.0, max=1.0),
                      _range(augment, "fold_depth", 0.0, 0.5)),
        fields.float("unsure_below", min=0.0, max=1.0), fields.float("max_fit_cost"))


def load_perception_config(path: str | Path | None = None) -> PerceptionConfig:
    """Load `config/perception.yaml` (or `path`); relative paths in it are against config/."""
    p = Path(path) if path is not None else config_dir() / "perception.yaml"
    return perception_config_from_fields(load_yaml(p), config_dir())
