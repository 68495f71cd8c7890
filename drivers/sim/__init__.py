"""The simulated garment world: shapes, layered folding physics, renderer, synthetic datasets.

Nothing is imported here: a process that reads only the sim's config does not load the physics."""
