"""`config/physics.yaml` loaded into frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_yaml


@dataclass(frozen=True)
class ClothConfig:
    areal_density: float        # kg/m2
    vertex_spacing: float       # m
    thickness: float            # m
    bending_rigidity: float     # N m
    poisson: float
    elastic_damping: float      # s
    edge_damping: float
    friction: float             # cloth on the table
    self_friction: float        # cloth on cloth (at most `friction`: a contact takes the larger)
    self_collision: str         # MuJoCo flex selfcollide: none | auto | narrow | bvh | sap
    crease_lines: bool = True   # mesh vertices along the recipe's fold lines (the crease forms on them)

    @property
    def young(self) -> float:
        """The shell's Young's modulus that gives `bending_rigidity`: D = E t^3 / (12 (1 - nu^2))."""
        return 12.0 * (1.0 - self.poisson ** 2) * self.bending_rigidity / self.thickness ** 3


@dataclass(frozen=True)
class SimulationConfig:
    timestep: float             # s
    settle: float               # s
    path_memory: float          # s of robot time of the grippers' path kept while nothing holds cloth
    solver: str                 # MuJoCo's constraint solver: CG | Newton | PGS
    tolerance: float            # its relative tolerance
    iterations: int             # and its iteration cap per step


@dataclass(frozen=True)
class GripperConfig:
    pinch_radius: float         # m
    pinch_height: float         # m
    max_pinched: int
    speed: float                # m/s
    dwell: float                # s
    lift_fraction: float        # synthetic folds (datasets): the path's apex over |grasp -> place|
    grasp_height: float         # m above the table at grasp and release of a synthetic fold


@dataclass(frozen=True)
class SilhouetteConfig:
    resolution: float           # m per pixel
    layer_area: float           # m2 a number of stacked layers must cover to count


@dataclass(frozen=True)
class PhysicsConfig:
    cloth: ClothConfig
    simulation: SimulationConfig
    gripper: GripperConfig
    silhouette: SilhouetteConfig


def physics_from_fields(f: Fields) -> PhysicsConfig:
    f.reject_unknown({"cloth", "simulation", "gripper", "silhouette"})
    c = f.sub("cloth")
    c.reject_unknown(set(ClothConfig.__dataclass_fields__))
    cloth = ClothConfig(
        areal_density=c.float("areal_density", positive=True, max=5.0),
        vertex_spacing=c.float("vertex_spacing", positive=True, max=0.2),
        thickness=c.float("thickness", positive=True, max=0.02),
        bending_rigidity=c.float("bending_rigidity", positive=True, max=1e-2),
        poisson=c.float("poisson", min=0.0, max=0.49),
        elastic_damping=c.float("elastic_damping", min=0.0),
        edge_damping=c.float("edge_damping", min=0.0),
        friction=c.float("friction", min=0.0, max=2.0),
        self_friction=c.float("self_friction", min=0.0, max=2.0),
        self_collision=c.str("self_collision", choices=("none", "auto", "narrow", "bvh", "sap")),
        crease_lines=c.bool("crease_lines"),
    )
    if cloth.self_friction > cloth.friction:
        raise c.error("self_friction", f"must be at most friction ({cloth.friction}): a contact takes the "
                                       f"larger friction of its two sides, got {cloth.self_friction}")
    s = f.sub("simulation")
    s.reject_unknown(set(SimulationConfig.__dataclass_fields__))
    simulation = SimulationConfig(timestep=s.float("timestep", positive=True, max=0.01),
                                  settle=s.float("settle", min=0.0),
                                  path_memory=s.float("path_memory", positive=True),
                                  solver=s.str("solver", choices=("CG", "Newton", "PGS")),
                                  tolerance=s.float("tolerance", positive=True, max=0.1),
                                  iterations=s.int("iterations", min=1, max=1000))
    g = f.sub("gripper")
    g.reject_unknown(set(GripperConfig.__dataclass_fields__))
    gripper = GripperConfig(
        pinch_radius=g.float("pinch_radius", positive=True, max=0.2),
        pinch_height=g.float("pinch_height", positive=True, max=0.1),
        max_pinched=g.int("max_pinched", min=1, max=64),
        speed=g.float("speed", positive=True, max=5.0),
        dwell=g.float("dwell", min=0.0),
        lift_fraction=g.float("lift_fraction", min=0.0, max=2.0),
        grasp_height=g.float("grasp_height", min=0.0, max=0.1),
    )
    m = f.sub("silhouette")
    m.reject_unknown(set(SilhouetteConfig.__dataclass_fields__))
    silhouette = SilhouetteConfig(resolution=m.float("resolution", positive=True, max=0.05),
                                  layer_area=m.float("layer_area", positive=True))
    return PhysicsConfig(cloth, simulation, gripper, silhouette)


def load_physics_config(path: str | Path | None = None) -> PhysicsConfig:
    return physics_from_fields(load_yaml(Path(path) if path is not None else config_dir() / "physics.yaml"))
