"""Garment categories and landmark names, the one list the simulated world, perception, planning
and the tools share.

Names, order and handedness follow the CloPeMa Garment Dataset (the design page's lists exactly):
`left` and `right` are the garment's own sides as worn, so on a garment lying face up (`facing:
front`) with its top towards the image top the wearer's left is on the image's right, and the
landmarks run clockwise on screen in `LANDMARKS` order. A garment lying face down (`facing: back`)
is the mirror image: the same names in the same order run counter-clockwise, the wearer's left on the
image's left; `mirror_name` turns the names of one facing into those of the other.

The dataset names a garment by its `type` and misspells a few landmark names; `TYPE_TO_CATEGORY` and
`canonical_name` read them (misspellings are read, never written).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

CATEGORIES: tuple[str, ...] = ("towel", "pants", "short-sleeve", "long-sleeve")

FACINGS: tuple[str, ...] = ("front", "back")

_SHIRT = ("bottom-left", "bottom-right", "right-armpit", "right-sleeve-inner", "right-sleeve-outer",
          "right-shoulder", "left-shoulder", "left-sleeve-outer", "left-sleeve-inner", "left-armpit")

# category -> landmark names of the design page (the polygonal models' vertices), in its order
LANDMARKS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "towel": ("bottom-left", "bottom-right", "top-right", "top-left"),
    "pants": ("left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner", "right-leg-outer",
              "top-right", "top-left"),
    "short-sleeve": _SHIRT,
    "long-sleeve": _SHIRT,
})

# the dataset's extra shirt nodes, in its order between `right-shoulder` and `left-shoulder`: where the
# neckline meets the shoulder line and the collar's tips at the bottom of the neckline (not model vertices)
SHIRT_NECK_NODES: tuple[str, ...] = ("neckline-right", "collar-right", "collar-left", "neckline-left")


def _with_neck(names: tuple[str, ...]) -> tuple[str, ...]:
    after = names.index("right-shoulder") + 1
    return names[:after] + SHIRT_NECK_NODES + names[after:]


# category -> every node the dataset annotates on a flat garment, in its order
ANNOTATED_NODES: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "towel": LANDMARKS["towel"],
    "pants": LANDMARKS["pants"],
    "short-sleeve": _with_neck(_SHIRT),
    "long-sleeve": _with_neck(_SHIRT),
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
    """The landmark's mirror image across the garment's vertical axis: left <-> right.

    A garment seen face down is the mirror image of one seen face up: the name a face-up reading
    gives a point of a face-down garment is the mirror of its true name, and the other way round.
    """
    if "left" in name:
        return name.replace("left", "right")
    if "right" in name:
        return name.replace("right", "left")
    return name
