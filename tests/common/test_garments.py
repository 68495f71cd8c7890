"""The shared garment vocabulary: categories, landmark names, the dataset's types and spellings."""

from __future__ import annotations

from drivers.common.garments import CATEGORIES, LANDMARKS, TYPE_TO_CATEGORY, canonical_name, mirror_name


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
