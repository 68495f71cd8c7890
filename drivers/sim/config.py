"""`config/sim.yaml` loaded into frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_fields, load_yaml, rule
from drivers.common.garments import CATEGORIES

SHAPES: tuple[str, ...] = ("flat", "wrinkled")
TEXTURES: tuple[str, ...] = ("twill", "terry", "pique", "knit")

Range = tuple[float, float]


@dataclass(frozen=True)
class Palette:
    bgr: tuple[float, ...]            # blue, green, red 0..255
    jitter: float
    texture: str


@dataclass(frozen=True)
class PoseConfig:
    rotation: float = rule(min=0.0, max=3.141592653589793)
    view_margin: float = rule(min=0.0)
    min_scale: float = rule(positive=True, max=1.0)
    face_down: float = rule(min=0.0, max=1.0)         # fraction of garments lying face down
    # table x and y the cell's scenes keep to; None: the view (given by the loader)
    cell_area: tuple[Range, Range] | None = rule()
    attempts: int = rule(min=1)
    place_attempts: int = rule(min=1)   # places tried for one garment at one rotation


@dataclass(frozen=True)
class EdgeConfig:
    spacing: float = rule(positive=True)
    flat_amplitude: float = rule(min=0.0)
    wrinkled_amplitude: float = rule(min=0.0)
    wavelength: tuple[float, float] = rule()       # a Range (given by the loader, as collar_corners)
    corner_ramp: float = rule(positive=True)
    sleeve_bow: float = rule(min=0.0)
    collar_spread: float = rule(min=0.0, max=0.9)
    # a collar's corners, fraction of the neckline's half width (a Range)
    collar_corners: tuple[float, float] = rule()


# how the world folds: cloth physics (MuJoCo) or the fast geometric layers (unit tests, datasets)
FOLDINGS: tuple[str, ...] = ("physics", "geometric")


@dataclass(frozen=True)
class FoldRulesConfig:
    """The geometric world's grasp and fold rules, and the fold convention's merge distance."""

    grasp_height: float = rule(min=0.0)
    grasp_edge_distance: float = rule(positive=True)
    agree_angle: float = rule(positive=True)
    agree_offset: float = rule(positive=True)
    crumple: float = rule(min=0.0, max=0.9)
    crumple_noise: float = rule(min=0.0)
    merge_fraction: float = rule(min=0.0, max=0.5)
    # m: a grasp-to-release that never lifted the cloth higher slid it
    drag_height: float = rule(positive=True, max=0.2)


@dataclass(frozen=True)
class TableLookConfig:
    """The simulated table's look: one physical table per `seed`, its values drawn from these ranges
    (`drivers.sim.render.draw_table_look`); the light's ranges are drawn per scene."""
    seed: int
    wood_bgr: tuple[tuple[float, ...], tuple[float, ...]]   # lowest and highest blue, green, red
    plank_width: Range                # m, drawn per plank
    plank_tint: Range                 # per-plank brightness variation
    grain_contrast: Range
    seam_darkness: Range
    seam_width: Range                 # m
    light_gradient: Range             # per scene: a linear brightness ramp across the image, any direction
    vignette: Range                   # per scene: corner darkening


def table_look_from_fields(f: Fields) -> TableLookConfig:
    f.reject_unknown(set(TableLookConfig.__dataclass_fields__))
    rows = f.raw("wood_bgr")
    if (not isinstance(rows, list) or len(rows) != 2 or not all(isinstance(row, list) and len(row) == 3
                                                                 for row in rows)):
        raise f.error("wood_bgr", f"must be [[b, g, r], [b, g, r]] (lowest, highest), got {rows!r}")
    try:
        low, high = (tuple(float(v) for v in row) for row in rows)
    except (TypeError, ValueError) as exc:
        raise f.error("wood_bgr", f"must hold numbers: {exc}") from exc
    if any(lo > hi or not 0 <= lo <= 255 or not 0 <= hi <= 255 for lo, hi in zip(low, high, strict=True)):
        raise f.error("wood_bgr", f"must be lowest <= highest within 0..255, got {rows!r}")

    def fraction(name: str) -> Range:
        lo, hi = _range(f, name)
        if lo < 0 or hi > 1:
            raise f.error(name, f"must lie within [0, 1], got {[lo, hi]}")
        return lo, hi

    def positive(name: str) -> Range:
        lo, hi = _range(f, name)
        if lo <= 0:
            raise f.error(name, f"must be positive, got {[lo, hi]}")
        return lo, hi

    return TableLookConfig(f.int("seed", min=0), (low, high), positive("plank_width"), fraction("plank_tint"),
                           fraction("grain_contrast"), fraction("seam_darkness"), positive("seam_width"),
                           fraction("light_gradient"), fraction("vignette"))


@dataclass(frozen=True)
class RenderConfig:
    table_look: TableLookConfig       # from the file's own `table_look` section (given to the loader)
    texture_resolution: float = rule(positive=True)
    floor_margin: float = rule(min=0.0)
    floor_bgr: tuple[float, ...] = rule(length=3)
    light_gain: float = rule(positive=True)
    bright_gain: float = rule(min=0.0)
    bright_sigma: float = rule(positive=True)
    bright_jitter: float = rule(min=0.0)
    exposure_jitter: float = rule(min=0.0)
    noise_sigma: float = rule(min=0.0)
    blur_sigma: float = rule(min=0.0)
    shadow_offset: tuple[float, ...] = rule(length=2)
    shadow_blur: int = rule(min=1)
    shadow_strength: float = rule(min=0.0, max=1.0)
    fold_edge_darkening: float = rule(min=0.0, max=1.0)
    fold_edge_width: int = rule(min=1)
    backside_shade: float = rule(positive=True)
    wrinkle_strength: float = rule(min=0.0)
    wrinkle_count: tuple[int, int] = rule()
    texture_strength: float = rule(min=0.0)
    mottle_strength: float = rule(min=0.0)
    table_like_fraction: float = rule(min=0.0, max=1.0)
    table_like_jitter: float = rule(min=0.0)
    png_compression: int = rule(min=0, max=9)


@dataclass(frozen=True)
class DatasetConfig:
    empty_table_every: int = rule(min=1)
    types: tuple[tuple[str, tuple[str, ...]], ...] = rule()   # (given by the loader, as folds)
    # `type` values whose garments have a collar (annotated collar-*)
    collared: tuple[str, ...] = rule()
    folds: tuple[tuple[str, int], ...] = rule()

    def types_of(self, category: str) -> tuple[str, ...]:
        return dict(self.types)[category]

    def folds_of(self, category: str) -> int:
        return dict(self.folds)[category]


@dataclass(frozen=True)
class SimConfig:
    garments: tuple[tuple[str, tuple[tuple[str, Range], ...]], ...]   # category -> parameter -> range
    corner_jitter: float
    pose: PoseConfig
    edges: EdgeConfig
    shape_weights: tuple[tuple[str, float], ...]
    folding: str                      # physics (cloth, config/physics.yaml) | geometric (fast)
    fold_rules: FoldRulesConfig
    render: RenderConfig
    palettes: tuple[tuple[str, tuple[Palette, ...]], ...]
    dataset: DatasetConfig

    def ranges(self, category: str) -> dict[str, Range]:
        return dict(dict(self.garments)[category])

    def palette(self, category: str) -> tuple[Palette, ...]:
        return dict(self.palettes)[category]


_GARMENT_PARAMS = {
    "towel": {"long_side", "aspect"},
    "pants": {"waist_width", "length", "rise", "hem_width", "leg_gap", "flare"},
    "short-sleeve": {"body_width", "body_length", "shoulder_width", "shoulder_drop", "armhole_depth",
                     "sleeve_length", "sleeve_width", "sleeve_angle", "neck_width", "neck_depth"},
}
_GARMENT_PARAMS["long-sleeve"] = _GARMENT_PARAMS["short-sleeve"]


def _range(f: Fields, name: str) -> Range:
    lo, hi = f.floats(name, length=2)
    if hi < lo:
        raise f.error(name, f"must be [low, high] with low <= high, got {[lo, hi]}")
    return (lo, hi)


def _collar_corners(f: Fields) -> Range:
    lo, hi = _range(f, "collar_corners")
    if lo <= 0.0 or hi >= 1.0:
        raise f.error("collar_corners", f"must lie strictly between 0 and 1 (the neckline's ends), "
                                        f"got {[lo, hi]}")
    return (lo, hi)


def load_sim_config(path: str | Path | None = None) -> SimConfig:
    path = Path(path) if path else config_dir() / "sim.yaml"
    f = load_yaml(path)
    f.reject_unknown({"garments", "pose", "edges", "shape_weights", "folding", "fold_rules", "render",
                      "palettes", "dataset", "table_look"})
    g = f.sub("garments")
    g.reject_unknown(set(CATEGORIES))
    garments = []
    corner_jitter = 0.0
    for cat in CATEGORIES:
        c = g.sub(cat)
        allowed = set(_GARMENT_PARAMS[cat]) | ({"corner_jitter"} if cat == "towel" else set())
        c.reject_unknown(allowed)
        garments.append((cat, tuple((p, _range(c, p)) for p in sorted(_GARMENT_PARAMS[cat]))))
        if cat == "towel":
            corner_jitter = c.float("corner_jitter", min=0.0)
    p = f.sub("pose")
    cell_area = None
    if p.raw("cell_area", None) is not None:
        area = p.sub("cell_area")
        area.reject_unknown({"x", "y"})
        cell_area = (_range(area, "x"), _range(area, "y"))
    e = f.sub("edges")
    sw = f.sub("shape_weights")
    sw.reject_unknown(set(SHAPES))
    pal = f.sub("palettes")
    pal.reject_unknown(set(CATEGORIES))
    palettes = []
    for cat in CATEGORIES:
        items = pal.items(cat)
        if not items:
            raise pal.error(cat, "must list at least one colour")
        entries = []
        for it in items:
            it.reject_unknown({"bgr", "jitter", "texture"})
            entries.append(Palette(it.floats("bgr", length=3), it.float("jitter", min=0.0),
                                   it.str("texture", choices=TEXTURES)))
        palettes.append((cat, tuple(entries)))
    d = f.sub("dataset")
    dt, dfo = d.sub("types"), d.sub("folds")
    dt.reject_unknown(set(CATEGORIES))
    dfo.reject_unknown(set(CATEGORIES))
    return SimConfig(
        garments=tuple(garments),
        corner_jitter=corner_jitter,
        pose=load_fields(PoseConfig, p, cell_area=cell_area),
        edges=load_fields(EdgeConfig, e, wavelength=_range(e, "wavelength"),
                          collar_corners=_collar_corners(e)),
        shape_weights=tuple((s, sw.float(s, min=0.0)) for s in SHAPES),
        folding=f.str("folding", choices=FOLDINGS),
        fold_rules=load_fields(FoldRulesConfig, f.sub("fold_rules")),
        render=load_fields(RenderConfig, f.sub("render"),
                           table_look=table_look_from_fields(f.sub("table_look"))),
        palettes=tuple(palettes),
        dataset=load_fields(DatasetConfig, d, types=tuple((c, dt.strs(c)) for c in CATEGORIES),
                            folds=tuple((c, dfo.int(c, min=1)) for c in CATEGORIES)),
    )


@lru_cache(maxsize=1)
def default_sim_config() -> SimConfig:
    return load_sim_config()
