"""The simulated garment world: shapes, layered folding physics, renderer, synthetic datasets."""

from drivers.sim.config import SimConfig, default_sim_config, load_sim_config
from drivers.sim.errors import SimError, SimInputError
from drivers.sim.world import GarmentWorld, GraspResult

__all__ = ["GarmentWorld", "GraspResult", "SimConfig", "SimError", "SimInputError",
           "default_sim_config", "load_sim_config"]
