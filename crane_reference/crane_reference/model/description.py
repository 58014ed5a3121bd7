"""A crane described as a serial chain of links (:class:`CraneDescription`), the form every layer above takes.

A description lists its links from the base outwards.  Each link hangs on its parent (the base or the link
before it) through one joint, revolute or prismatic, and is either a rigid body or a uniform beam that the
chain builder (:mod:`crane_reference.model.chain`) cuts into rigid finite elements (:mod:`.rfe`).

Frames, as URDF has them:

* the world frame: z up, gravity along -z.  A fixed base is the world frame; a sprung base moves on its
  support springs by q~(1) = (x, y, z, psi, theta, phi) (eq. (1)) from the world frame.
* a joint's ``origin`` is the transform from its parent link's frame to the joint frame at q = 0; its motion
  is a rotation about, or a translation along, the unit ``axis`` of the joint frame; the link's frame is
  the joint frame after that motion.  A flexible link's frame is that of its undeformed beam at the root:
  x along the beam axis.  A child of a flexible link is attached to the beam's last element (its tip).
* masses, centres of mass and inertias about the centre of mass are given in the link's own frame.

Sign conventions: a joint spring k and damper c act as -k q - c qd on their joint (the spring is relaxed at
q = 0: put the joint's origin where it is relaxed); the drive's generalized force is positive along +q.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .parameters import BeamSection, FlexibleDrive, RigidBody, SupportSpring, Task, TorqueDrive

REVOLUTE = "revolute"
PRISMATIC = "prismatic"
JOINT_TYPES = (REVOLUTE, PRISMATIC)
BASE = "base"
"""The name a crane file gives as a link's ``parent`` when it hangs on the base (the world frame for a fixed base);
in a :class:`LinkDescription` that parent is None."""
BASE_JOINTS = ("base_x", "base_y", "base_z", "base_yaw", "base_pitch", "base_roll")
"""The coordinates q~(1) of a sprung base, in the order of eq. (1)."""


@dataclass(frozen=True)
class JointDescription:
    """One joint: ``kind`` revolute or prismatic about / along the unit ``axis`` (3,) of the joint frame,
    ``origin`` (4, 4) the transform from the parent link's frame; ``initial`` its position in the start
    configuration [rad or m]; optional ``limits`` (lower, upper) [rad or m], for the URDF and for the user's
    checks; a spring ``stiffness`` [N m/rad or N/m] and a ``damping`` [N m s/rad or N s/m] about q = 0."""

    name: str
    kind: str
    axis: np.ndarray
    origin: np.ndarray
    initial: float = 0.0
    limits: tuple[float, float] | None = None
    stiffness: float = 0.0
    damping: float = 0.0


@dataclass(frozen=True)
class Beam:
    """A uniform beam along its link's x axis, discretised by the RFE rule of :mod:`.rfe`: ``length`` [m],
    ``section`` (I_y, I_z about the link's y and z axes), Young's and shear moduli [Pa], ``density`` [kg/m^3],
    ``rfe_count`` elements and the stiffness-proportional (Rayleigh beta) ``damping`` [s] of its spring-damping
    elements.  ``vertical_axis`` ("y" or "z") is the link axis that is up in the beam's plane of motion (the
    luffing plane): y for the paper's boom frames (z along the luff axis), z for link frames with z up; it names
    the RFE angles (``bend_vertical``, bending in that plane, ``bend_lateral``) and the deflection signals."""

    length: float
    section: BeamSection
    youngs_modulus: float
    shear_modulus: float
    density: float
    rfe_count: int
    damping: float = 0.0
    vertical_axis: str = "y"


@dataclass(frozen=True)
class LinkDescription:
    """A link on its ``parent`` (a link's name, or None: the base) through ``joint``: a rigid ``body`` or a
    flexible ``beam`` (at most one of the two; neither: a frame without mass, as a URDF link may be)."""

    name: str
    parent: str | None
    joint: JointDescription
    body: RigidBody | None = None
    beam: Beam | None = None


@dataclass(frozen=True)
class SprungBase:
    """A base of mass ``body`` (in the base frame) on ``supports``, with stiffness-proportional damping
    ``damping`` [s] on them."""

    body: RigidBody
    supports: tuple[SupportSpring, ...]
    damping: float = 0.0


@dataclass(frozen=True)
class PointOnLink:
    """A point ``point`` (3,) [m] of link ``link``, in the link's frame."""

    link: str
    point: np.ndarray


@dataclass(frozen=True)
class CraneDescription:
    """A crane: its chain, drive, actuators and task.

    ``base`` is a :class:`SprungBase` or None (fixed); ``links`` are in chain order, from the base out.
    ``drive`` acts on ``drive_joint``; ``actuated`` names the joints with actuators (a controller's joints).
    E is ``end_effector``; ``payload`` a point mass [kg] at ``payload_at`` (E's point by default).
    ``dependent`` names the coordinates (3.2) the task constraints solve for, one per constraint, or is
    None: chosen at the start from the best-conditioned minor of the task Jacobian
    (:func:`crane_reference.motion.simulation.choose_dependent`).  ``task`` holds the targets (5.1)-(5.2).
    ``name`` names the robot in its URDF."""

    name: str
    gravity: float
    base: SprungBase | None
    links: tuple[LinkDescription, ...]
    drive: TorqueDrive | FlexibleDrive
    drive_joint: str
    actuated: tuple[str, ...]
    end_effector: PointOnLink
    dependent: tuple[str, ...] | None = None
    payload: float = 0.0
    payload_at: PointOnLink | None = None
    task: Task = field(default_factory=Task)

    @property
    def joints(self) -> tuple[JointDescription, ...]:
        """The links' joints in chain order (the base's coordinates and the RFE angles are not among them)."""
        return tuple(link.joint for link in self.links)

    def joint(self, name: str) -> JointDescription:
        """The joint called ``name``."""
        for joint in self.joints:
            if joint.name == name:
                return joint
        raise KeyError(f"no joint {name!r}; the description's joints: {', '.join(j.name for j in self.joints)}")

    @property
    def drive_start(self) -> float:
        """The drive joint's initial position (where a spring drive's motor angle starts)."""
        return self.joint(self.drive_joint).initial

    @property
    def flexible_links(self) -> tuple[LinkDescription, ...]:
        return tuple(link for link in self.links if link.beam is not None)

    def with_rfe_count(self, count: int) -> CraneDescription:
        """The same crane with ``count`` rigid finite elements in every flexible link."""
        return self._with_beams(rfe_count=count)

    def with_beam_damping(self, beta: float) -> CraneDescription:
        """The same crane with the Rayleigh beta ``beta`` [s] on every flexible link."""
        return self._with_beams(damping=beta)

    def with_beam_stiffness(self, factor: float) -> CraneDescription:
        """The same crane with every flexible link's moduli E and G scaled by ``factor``."""
        return replace(self, links=tuple(
            link if link.beam is None else replace(link, beam=replace(
                link.beam, youngs_modulus=link.beam.youngs_modulus * factor,
                shear_modulus=link.beam.shear_modulus * factor)) for link in self.links))

    def _with_beams(self, **changes: object) -> CraneDescription:
        return replace(self, links=tuple(
            link if link.beam is None else replace(link, beam=replace(link.beam, **changes)) for link in self.links))
