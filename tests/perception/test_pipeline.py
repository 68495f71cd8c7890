"""End to end on rendered images: category, landmarks, costs of every model, timings."""

from __future__ import annotations

import numpy as np
import pytest

from cell.perception import CATEGORIES, perceive
from cell.perception.errors import ModelError
from cell.perception.synthetic import random_garment, render


def test_every_category_recognised_and_located(fitted_perception) -> None:  # noqa: ANN001
    cfg, table, models = fitted_perception
    rng = np.random.default_rng(77)
    errors = []
    for c in CATEGORIES:
        for _ in range(2):
            g = random_garment(c, rng)
            obs = perceive(render(g, rng), table, models, cfg, None)
            assert obs.category == c
            assert set(obs.costs) == set(CATEGORIES) and obs.cost == min(obs.costs.values())
            assert set(obs.timings_ms) == {"segment", "simplify", "match", "total"}
            truth = dict(zip(g.names, g.landmarks))
            errors += [np.linalg.norm(np.subtract(obs.landmarks[n], truth[n])) for n in g.names]
            js = obs.to_json()
            assert len(js["polygon"]) == models[c].simplify_vertices
    assert np.median(errors) < 3.0


def test_unknown_category_is_an_error(fitted_perception) -> None:  # noqa: ANN001
    cfg, table, models = fitted_perception
    with pytest.raises(ModelError, match="no model"):
        perceive(np.zeros((1024, 1280, 3), np.uint8), table, models, cfg, "hat")
