"""Exceptions of the perception area; each message names the input and the reason."""

from __future__ import annotations


class PerceptionError(Exception):
    """Base class: perception could not produce an observation."""


class ImageError(PerceptionError):
    """The image is unreadable, empty or of the wrong shape or type."""


class NoGarmentFound(PerceptionError):
    """Segmentation found no garment-sized region on the table."""


class GarmentTouchesBorder(PerceptionError):
    """The garment region reaches the image border, so its outline is incomplete."""


class ModelError(PerceptionError):
    """A polygonal or table model is invalid or does not fit the input."""
