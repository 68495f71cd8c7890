"""docs/landmarks.jpg: two face-up simulated garments perceived and drawn as `perceive --overlay` does.

Run: .venv/bin/python -m docs.landmarks
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_garment_models, load_table_model, perceive
from drivers.sim.config import default_sim_config
from drivers.sim.dataset import build_world
from tools.overlay import draw_overlay

SCENES = (("short-sleeve", 3), ("pants", 5))
TILE_WIDTH = 800            # px; the height follows the overlay's (its title band on top)


def main() -> None:
    config = load_perception_config()
    table = load_table_model(None, config)
    models = load_garment_models(config)
    sim = default_sim_config()
    # nearly upright and face up, so the picture shows the convention plainly
    sim = replace(sim, pose=replace(sim.pose, rotation=0.12, face_down=0.0))
    tiles = []
    for category, seed in SCENES:
        image = build_world(seed, category, config=sim).render()
        observation = perceive(image, table, models, config, None)
        drawn = draw_overlay(image, observation, "front", observation.confidence)
        height = round(drawn.shape[0] * TILE_WIDTH / drawn.shape[1])
        tiles.append(cv2.resize(drawn, (TILE_WIDTH, height), interpolation=cv2.INTER_AREA))
    cv2.imwrite("docs/landmarks.jpg", np.hstack(tiles), [cv2.IMWRITE_JPEG_QUALITY, 85])


if __name__ == "__main__":
    main()
