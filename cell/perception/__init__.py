"""Garment perception (paper Sec. III): segmentation, polygon simplification, model matching.

Pure functions on numpy arrays and frozen dataclasses; pixels of the input image throughout.
"""

from .config import PerceptionConfig, load_perception_config
from .errors import GarmentTouchesBorder, ImageError, ModelError, NoGarmentFound, PerceptionError
from .folded import derive_folded_model, folded_polygon
from .matching import MatchResult, MatchWeights, match
from .models import CATEGORIES, DESIGN_LANDMARKS, PolygonalModel, learn_model
from .pipeline import (
                     Observation,
                     load_garment_model,
                     load_garment_models,
                     load_table_model,
                     perceive,
                     simplify_contour,
)
from .segmentation import Segmentation, segment
from .simplify import simplify_closed
from .table_model import TableModel, fit_table_model

__all__ = [
    "CATEGORIES", "DESIGN_LANDMARKS", "GarmentTouchesBorder", "ImageError", "MatchResult", "MatchWeights",
    "ModelError", "NoGarmentFound", "Observation", "PerceptionConfig", "PerceptionError", "PolygonalModel",
    "Segmentation", "TableModel", "derive_folded_model", "fit_table_model", "folded_polygon", "learn_model",
    "load_garment_model", "load_garment_models", "load_perception_config", "load_table_model", "match",
    "perceive", "segment", "simplify_closed", "simplify_contour",
]
