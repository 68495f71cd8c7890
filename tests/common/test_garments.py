"""The shared garment vocabulary: categories, landmark names, the dataset's types and spellings."""

from __future__ import annotations

from drivers.common.garments import (
    ANNOTATED_NODES,
    CATEGORIES,
    FACINGS,
    LANDMARKS,
    SHIRT_NECK_NODES,
    TYPE_TO_CATEGORY,
    canonical_name,
    mirror_name,
)


def test_every_category_has_its_landmarks_and_types() -> None:
    assert set(LANDMARKS) == set(CATEGORIES)
    assert set(TYPE_TO_CATEGORY.values()) == set(CATEGORIES)
    for names in LANDMARKS.values():
        assert len(set(names)) == len(names)
        # left and right come in pairs
        assert {mirror_name(n) for n in names} == set(names)
    assert TYPE_TO_CATEGORY["tshirt"] == "short-sleeve" and TYPE_TO_CATEGORY["sweater"] == "long-sleeve"


def test_names_read_and_mirror() -> None:
    assert canonical_name(" rigth-sleave-outer ") == "right-sleeve-outer"
    assert mirror_name("left-armpit") == "right-armpit" and mirror_name("right-leg-inner") == "left-leg-inner"
    assert mirror_name("crotch") == "crotch"


def test_landmarks_are_the_design_pages_lists_in_the_datasets_order() -> None:
    # design.md "Garment categories and landmarks" (the CloPeMa dataset's order and handedness)
    shirt = ("bottom-left", "bottom-right", "right-armpit", "right-sleeve-inner", "right-sleeve-outer",
             "right-shoulder", "left-shoulder", "left-sleeve-outer", "left-sleeve-inner", "left-armpit")
    assert dict(LANDMARKS) == {
        "towel": ("bottom-left", "bottom-right", "top-right", "top-left"),
        "pants": ("left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner", "right-leg-outer",
                  "top-right", "top-left"),
        "short-sleeve": shirt,
        "long-sleeve": shirt,
    }
    # the polo of the dataset's examples: 14 nodes, the neckline and collar between the shoulders
    assert ANNOTATED_NODES["short-sleeve"] == (
        "bottom-left", "bottom-right", "right-armpit", "right-sleeve-inner", "right-sleeve-outer",
        "right-shoulder", "neckline-right", "collar-right", "collar-left", "neckline-left", "left-shoulder",
        "left-sleeve-outer", "left-sleeve-inner", "left-armpit")
    assert SHIRT_NECK_NODES == ("neckline-right", "collar-right", "collar-left", "neckline-left")
    assert ANNOTATED_NODES["pants"] == LANDMARKS["pants"] and FACINGS == ("front", "back")
