"""Collision checking of the whole cell (both arms, grippers, turn-table, table, cameras).

Shapes come from the URDF's <collision> elements (cylinders are read as capsules, see the URDF
header). Checked pairs: every pair of shapes on different, non-adjacent bodies, minus pairs that
collide in (nearly) every sampled configuration (like MoveIt's setup assistant). The gripper
fingers may touch the table top during grasp and release: checks for those segments pass
`allow_finger_contact=True`.

Two backends share the same pairs: python-fcl (the design card's choice) and coal through
pinocchio (`pin.computeCollisions`, all pairs in C++). `make bench` (tests/bench/bench_planning.py)
measures both on the full cell (186 pairs): coal 0.018 ms, python-fcl 0.13 ms per configuration
(about 7x), so the planner uses `backend: coal` from config/planning.yaml; python-fcl stays as
the reference implementation (and names the colliding shapes in messages), cross-checked against
coal in the tests.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import coal
import fcl
import numpy as np
import pinocchio as pin

from drivers.common.configfile import rule
from drivers.robot.kinematics import CellKinematics

log = logging.getLogger(__name__)

BACKENDS = ("coal", "fcl")


@dataclass(frozen=True)
class CollisionParams:
    backend: str = rule(choices=BACKENDS)
    finger_links: tuple[str, ...] = rule()    # shapes allowed to touch the table during grasp/release
    table_link: str = rule()
    disable_samples: int = rule(min=1)        # random configurations used to find always-colliding pairs
    # a pair colliding in more than this fraction is not checked
    disable_fraction: float = rule(min=0.0, max=1.0)


class CollisionChecker:
    """Is a configuration (13 joints, project order) free of collisions? Not thread-safe."""

    def __init__(self, kin: CellKinematics, params: CollisionParams, seed: int = 0):
        if params.backend not in BACKENDS:
            raise ValueError(f"collision backend must be one of {BACKENDS}, got {params.backend!r}")
        self.kin = kin
        self.params = params
        self.model = kin.model
        self.data = kin.model.createData()
        gm = pin.buildGeomFromUrdf(self.model, str(kin.urdf_path), pin.GeometryType.COLLISION)
        # URDF has no capsule: its cylinders stand for capsules.
        for go in gm.geometryObjects:
            if isinstance(go.geometry, coal.Cylinder):
                go.geometry = coal.Capsule(go.geometry.radius, 2.0 * go.geometry.halfLength)
        self.geom_model = gm
        self.names = [go.name for go in gm.geometryObjects]
        self.links = [self.model.frames[go.parentFrame].name for go in gm.geometryObjects]
        pairs = self._candidate_pairs()
        gm.removeAllCollisionPairs()
        for a, b in pairs:
            gm.addCollisionPair(pin.CollisionPair(a, b))
        self.geom_data = pin.GeometryData(gm)
        self._disable_always_colliding(seed)
        self.pairs = [(cp.first, cp.second) for cp in gm.collisionPairs]
        finger = set(params.finger_links)
        self.contact_pairs = {
            k for k, (a, b) in enumerate(self.pairs)
            if {self.links[a], self.links[b]} & finger and params.table_link in (self.links[a], self.links[b])
        }
        self.geom_data_contact = pin.GeometryData(gm)
        for k in self.contact_pairs:
            self.geom_data_contact.deactivateCollisionPair(k)
        self._build_fcl()
        log.debug("collision model: %d shapes, %d pairs", len(self.names), len(self.pairs))

    # --- pair selection -------------------------------------------------------------------
    def _candidate_pairs(self) -> list[tuple[int, int]]:
        gm, parents = self.geom_model, self.model.parents
        out = []
        n = len(gm.geometryObjects)
        for a in range(n):
            ja = gm.geometryObjects[a].parentJoint
            for b in range(a + 1, n):
                jb = gm.geometryObjects[b].parentJoint
                if ja == jb or parents[ja] == jb or parents[jb] == ja:
                    continue
                out.append((a, b))
        return out

    def _disable_always_colliding(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        robot = self.kin.robot
        counts = np.zeros(len(self.geom_model.collisionPairs))
        samples = self.params.disable_samples
        for _ in range(samples):
            q = rng.uniform(robot.lower, robot.upper)
            pin.computeCollisions(self.model, self.data, self.geom_model, self.geom_data,
                                  self.kin.to_pin(q), False)
            for k, res in enumerate(self.geom_data.collisionResults):
                counts[k] += res.isCollision()
        drop = [k for k in range(len(counts)) if counts[k] > self.params.disable_fraction * samples]
        for k in sorted(drop, reverse=True):
            cp = self.geom_model.collisionPairs[k]
            log.debug("not checking %s / %s (always in contact)", self.names[cp.first], self.names[cp.second])
            self.geom_model.removeCollisionPair(cp)
        self.geom_data = pin.GeometryData(self.geom_model)

    # --- fcl backend ----------------------------------------------------------------------
    def _build_fcl(self) -> None:
        self.fcl_objects = []
        for go in self.geom_model.geometryObjects:
            g = go.geometry
            if isinstance(g, coal.Capsule):
                shape = fcl.Capsule(g.radius, 2.0 * g.halfLength)
            elif isinstance(g, coal.Box):
                shape = fcl.Box(*(2.0 * np.asarray(g.halfSide)))
            else:
                raise ValueError(
                    f"collision shape {go.name}: only boxes and cylinders (capsules) are supported")
            self.fcl_objects.append(fcl.CollisionObject(shape, fcl.Transform()))
        self.fcl_request = fcl.CollisionRequest()
        self.fcl_pairs_contact = [p for k, p in enumerate(self.pairs) if k not in self.contact_pairs]

    def _fcl_collisions(self, q: np.ndarray, allow_finger_contact: bool,
                        first: bool) -> list[tuple[int, int]]:
        pin.updateGeometryPlacements(self.model, self.data, self.geom_model, self.geom_data,
                                     self.kin.to_pin(q))
        for obj, M in zip(self.fcl_objects, self.geom_data.oMg, strict=True):
            obj.setTransform(fcl.Transform(M.rotation, M.translation))
        hits = []
        pairs = self.fcl_pairs_contact if allow_finger_contact else self.pairs
        for a, b in pairs:
            res = fcl.CollisionResult()
            if fcl.collide(self.fcl_objects[a], self.fcl_objects[b], self.fcl_request, res):
                hits.append((a, b))
                if first:
                    break
        return hits

    # --- public ---------------------------------------------------------------------------
    def in_collision(self, q: np.ndarray, allow_finger_contact: bool = False,
                     backend: str | None = None) -> bool:
        backend = backend or self.params.backend
        if backend == "fcl":
            return bool(self._fcl_collisions(q, allow_finger_contact, True))
        gd = self.geom_data_contact if allow_finger_contact else self.geom_data
        return bool(pin.computeCollisions(self.model, self.data, self.geom_model, gd,
                                          self.kin.to_pin(q), True))

    def colliding_pairs(self, q: np.ndarray, allow_finger_contact: bool = False) -> list[tuple[str, str]]:
        """Names of the shapes in contact (for messages); uses python-fcl."""
        hits = self._fcl_collisions(q, allow_finger_contact, False)
        return [(self.names[a], self.names[b]) for a, b in hits]


__all__ = ["BACKENDS", "CollisionChecker", "CollisionParams"]
