"""Garment perception (paper Sec. III): segmentation, polygon simplification, model matching.

Pure functions on numpy arrays and frozen dataclasses; pixels of the input image throughout.
Categories and landmark names are shared with the rest of the cell: `drivers.common.garments`.
"""

from .config import PerceptionConfig, load_perception_config
from .errors import GarmentTouchesBorder, ImageError, ModelError, NoGarmentFound, PerceptionError
from .folded import derive_folded_model, folded_polygon
from .matching import MatchResult, MatchWeights, match
from .models import PolygonalModel, learn_model
from .pipeline import (
    Observation,
    Outline,
    extract_outline,
    load_garment_model,
    load_garment_models,
    load_table_model,
    match_outline,
    perceive,
    simplify_contour,
)
from .segmentation import Segmentation, segment
from .simplify import simplify_closed
from .table_model import TableModel, fit_table_model

__all__ = [
    "GarmentTouchesBorder", "ImageError", "MatchResult", "MatchWeights", "ModelError", "NoGarmentFound",
    "Observation", "Outline", "PerceptionConfig", "PerceptionError", "PolygonalModel", "Segmentation",
    "TableModel", "derive_folded_model", "extract_outline", "fit_table_model", "folded_polygon",
    "learn_model",
    "load_garment_model", "load_garment_models", "load_perception_config", "load_table_model", "match",
    "match_outline", "perceive", "segment", "simplify_closed", "simplify_contour",
]
