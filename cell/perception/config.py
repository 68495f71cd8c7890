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


@dataclass(frozen=True)
class TableFitConfig:
    components: int = 3
    em_iterations: int = 100
    covariance_floor: float = 1.0
    samples: int = 60000
    gain_grid: tuple[int, int] = (8, 10)
    min_cell_coverage: float = 0.2
    annotation_margin_px: int = 25


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


def _grid(f: Fields, name: str) -> tuple[int, int]:
    grid = f.raw(name)
    if not (isinstance(grid, list) and len(grid) == 2 and all(isinstance(v, int) and v >= 1 for v in grid)):
        raise f.error(name, f"must be [rows, cols] positive integers, got {grid!r}")
    return (grid[0], grid[1])


def perception_config_from_fields(f: Fields, base: Path) -> PerceptionConfig:
    f.reject_unknown({"table_model", "garments_dir", "segmentation", "table", "simplify", "matching",
                      "models", "folded", "table_fallback"})
    s = f.sub("segmentation")
    s.reject_unknown(set(SegmentationConfig.__dataclass_fields__))
    ws = s.raw("work_size")
    if not (isinstance(ws, list) and len(ws) == 2 and all(isinstance(v, int) and v >= 16 for v in ws)):
        raise s.error("work_size", f"must be [width, height] integers >= 16, got {ws!r}")
    seg = SegmentationConfig(
        (ws[0], ws[1]), s.float("quantile_fg", min=0.0, max=0.5), s.float("fraction_bg", min=0.0, max=1.0),
        s.int("grabcut_iterations", min=1, max=20), s.float("grabcut_converged_fraction", min=0.0, max=1.0),
        s.float("min_area_fraction", min=0.0, max=1.0),
        s.int("border_margin_px", min=0, max=50), s.int("refine_band_px", min=0, max=50),
        s.float("garment_var_floor", positive=True), s.int("grabcut_margin_px", min=1, max=100),
        s.int("sure_fg_radius_px", min=0, max=20), s.int("refine_passes", min=1, max=20),
        s.bool("adapt_light"), s.float("light_mahalanobis", positive=True),
        s.float("light_max_log_change", positive=True),
        s.float("light_min_fraction", min=0.0, max=1.0), _grid(s, "light_grid"),
        s.int("light_sample_stride", min=1, max=16),
        s.int("saturation_level", min=1, max=255), s.float("glare_chroma_tolerance", positive=True),
        s.float("glare_mahalanobis", positive=True),
        s.float("glare_context_px", positive=True),
        s.float("glare_max_brightness", positive=True), s.int("grabcut_components", min=1, max=5),
        s.int("grabcut_sample_stride", min=1, max=16), s.float("grabcut_var_floor", positive=True),
        s.float("min_table_blob_fraction", min=0.0, max=0.5), s.bool("grabcut_flat_light"),
        s.int("spur_radius_px", min=0, max=20), s.bool("open_slits"),
        s.int("slit_min_width_px", min=0, max=20), s.float("slit_mahalanobis", positive=True),
        s.float("grabcut_keep_fraction", min=0.0, max=1.0), s.bool("unknown_table_hue_fixed"))
    t = f.sub("table")
    t.reject_unknown(set(TableFitConfig.__dataclass_fields__))
    grid = t.raw("gain_grid")
    if not (isinstance(grid, list) and len(grid) == 2 and all(isinstance(v, int) and v >= 1 for v in grid)):
        raise t.error("gain_grid", f"must be [rows, cols] positive integers, got {grid!r}")
    tab = TableFitConfig(t.int("components", min=1, max=16), t.int("em_iterations", min=1),
                         t.float("covariance_floor", positive=True), t.int("samples", min=100),
                         (grid[0], grid[1]), t.float("min_cell_coverage", min=0.0, max=1.0),
                         t.int("annotation_margin_px", min=0))
    sm = f.sub("simplify")
    sm.reject_unknown(set(SimplifyConfig.__dataclass_fields__))
    simp = SimplifyConfig(sm.float("candidate_tolerance_px", positive=True),
                          sm.int("max_candidates", min=4, max=200),
                          sm.float("expected_vertex_gap", min=0.0, max=0.5))
    m = f.sub("matching")
    m.reject_unknown({"lambda_vertex", "lambda_edge", "lambda_segment", "straight_mean", "straight_var",
                      "upright_margin", "lambda_position", "position_sigma_fraction"})
    w = MatchWeights(m.float("lambda_vertex", min=0.0), m.float("lambda_edge", min=0.0),
                     m.float("lambda_segment", min=0.0), m.float("straight_mean"),
                     m.float("straight_var", positive=True), m.float("upright_margin", min=0.0),
                     m.float("lambda_position", min=0.0), m.float("position_sigma_fraction", positive=True))
    fo = f.sub("folded")
    fo.reject_unknown({"merge_fraction"})
    mo = f.sub("models")
    mo.reject_unknown({"angle_var_floor", "length_var_floor"})
    tf = f.sub("table_fallback")
    tf.reject_unknown(set(TableFallbackConfig.__dataclass_fields__))
    fallback = TableFallbackConfig(tf.bool("enabled"), tf.float("border_fraction", positive=True, max=0.25),
                                   tf.float("min_table_fraction", min=0.0, max=1.0))
    return PerceptionConfig(base / f.str("table_model"), base / f.str("garments_dir"), seg, tab, simp, w,
                            fo.float("merge_fraction", min=0.0, max=0.5),
                            mo.float("angle_var_floor", positive=True),
                            mo.float("length_var_floor", positive=True), fallback)


def load_perception_config(path: str | Path | None = None) -> PerceptionConfig:
    """Load `config/perception.yaml` (or `path`); relative paths in it are against config/."""
    p = Path(path) if path is not None else config_dir() / "perception.yaml"
    return perception_config_from_fields(load_yaml(p), config_dir())
