"""`config/physics.yaml` loaded into frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_fields, load_yaml, rule


@dataclass(frozen=True)
class ClothConfig:
    areal_density: float = rule(positive=True, max=5.0)        # kg/m2
    vertex_spacing: float = rule(positive=True, max=0.2)       # m
    thickness: float = rule(positive=True, max=0.02)           # m
    bending_rigidity: float = rule(positive=True, max=1e-2)    # N m
    poisson: float = rule(min=0.0, max=0.49)
    elastic_damping: float = rule(min=0.0)                     # s
    edge_damping: float = rule(min=0.0)
    friction: float = rule(min=0.0, max=2.0)                   # cloth on the table
    # cloth on cloth (at most `friction`: a contact takes the larger)
    self_friction: float = rule(min=0.0, max=2.0)
    # MuJoCo flex selfcollide: none | auto | narrow | bvh | sap
    self_collision: str = rule(choices=("none", "auto", "narrow", "bvh", "sap"))
    # mesh vertices along the recipe's fold lines (the crease forms on them)
    crease_lines: bool = rule(default=True)

    @property
    def young(self) -> float:
        """The shell's Young's modulus that gives `bending_rigidity`: D = E t^3 / (12 (1 - nu^2))."""
        return 12.0 * (1.0 - self.poisson ** 2) * self.bending_rigidity / self.thickness ** 3


@dataclass(frozen=True)
class SimulationConfig:
    timestep: float = rule(positive=True, max=0.01)            # s
    settle: float = rule(min=0.0)                              # s
    # s of robot time of the grippers' path kept while nothing holds cloth
    path_memory: float = rule(positive=True)
    solver: str = rule(choices=("CG", "Newton", "PGS"))        # MuJoCo's constraint solver
    tolerance: float = rule(positive=True, max=0.1)            # its relative tolerance
    iterations: int = rule(min=1, max=1000)                    # and its iteration cap per step


@dataclass(frozen=True)
class GripperConfig:
    pinch_radius: float = rule(positive=True, max=0.2)         # m
    pinch_height: float = rule(positive=True, max=0.1)         # m
    max_pinched: int = rule(min=1, max=64)
    speed: float = rule(positive=True, max=5.0)                # m/s
    dwell: float = rule(min=0.0)                               # s
    # synthetic folds (datasets): the path's apex over |grasp -> place|
    lift_fraction: float = rule(min=0.0, max=2.0)
    # m above the table at grasp and release of a synthetic fold
    grasp_height: float = rule(min=0.0, max=0.1)


@dataclass(frozen=True)
class SilhouetteConfig:
    resolution: float = rule(positive=True, max=0.05)          # m per pixel
    layer_area: float = rule(positive=True)    # m2 a number of stacked layers must cover to count


@dataclass(frozen=True)
class PhysicsConfig:
    cloth: ClothConfig = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    simulation: SimulationConfig = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    gripper: GripperConfig = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    silhouette: SilhouetteConfig = rule(section=True)  # noqa: RUF009 - a frozen dataclass


def physics_from_fields(f: Fields) -> PhysicsConfig:
    config = load_fields(PhysicsConfig, f)
    cloth = config.cloth
    if cloth.self_friction > cloth.friction:
        raise f.sub("cloth").error("self_friction", f"must be at most friction ({cloth.friction}): a contact "
                                   f"takes the larger friction of its two sides, got {cloth.self_friction}")
    return config


def load_physics_config(path: str | Path | None = None) -> PhysicsConfig:
    return physics_from_fields(load_yaml(Path(path) if path is not None else config_dir() / "physics.yaml"))
