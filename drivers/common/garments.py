"""Garment categories and landmark names, the one list the simulated world, perception, planning
and the tools share.

Landmark names follow the design page, in its order (counter-clockwise on screen for towel and pants,
clockwise for the shirts). The CloPeMa dataset names a garment by its `type` and misspells a few
landmark names; `TYPE_TO_CATEGORY` and `canonical_name` read them.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

CATEGORIES: tuple[str, ...] = ("towel", "pants", "short-sleeve", "long-sleeve")

_SHIRT = ("bottom-left", "left-armpit", "left-sleeve-inner", "left-sleeve-outer", "left-shoulder",
          "right-shoulder", "right-sleeve-outer", "right-sleeve-inner", "right-armpit", "bottom-right")

# category -> landmark names of the design page, in its order
LANDMARKS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "towel": ("bottom-left", "bottom-right", "top-right", "top-left"),
    "pants": ("left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner", "right-leg-outer",
              "top-right", "top-left"),
    "short-sleeve": _SHIRT,
    "long-sleeve": _SHIRT,
})

# the dataset's `type` field -> category
TYPE_TO_CATEGORY: Mapping[str, str] = MappingProxyType({
    "towel": "towel", "pants": "pants", "tshirt": "short-sleeve", "polo": "short-sleeve",
    "shirt": "long-sleeve", "sweater": "long-sleeve",
    "short-sleeve": "short-sleeve", "long-sleeve": "long-sleeve",
})


def canonical_name(name: str) -> str:
    """A landmark name as the design spells it (the dataset writes `rigth` and `sleave`)."""
    return name.strip().replace("rigth", "right").replace("sleave", "sleeve")


def mirror_name(name: str) -> str:
    """The landmark's mirror image across the garment's vertical axis: left <-> right."""
    if "left" in name:
        return name.replace("left", "right")
    if "right" in name:
        return name.replace("right", "left")
    return name
