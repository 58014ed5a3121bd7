"""The crane as a serial kinematic chain of one-DOF joints (:class:`ChainModel`), built from a
:class:`~crane_reference.model.description.CraneDescription`.

Every generalized coordinate of eq. (1) is one joint of the chain, from the base outwards: a sprung base's
six coordinates q~(1) = (x, y, z, psi, theta, phi) (``base_x`` ... ``base_roll``), then each link's joint,
each flexible link's joint followed by the three RFE angles of each of its spring-damping elements
(``<link>_sde{r}_bend_vertical`` / ``_bend_lateral`` / ``_twist``, r = 1 .. n_rfe - 1, :mod:`.rfe`).  For
the paper's crane (``config/crane.yaml``)::

    base_x base_y base_z base_yaw base_pitch base_roll   q~(1) = x y z psi theta phi
    column_slew                                          q~(2) = psi2
    boom_luff                                            q~(3,0) = psi(3,0)
    boom_sde{r}_bend_vertical / _bend_lateral / _twist   q~(3,r) = psi theta phi, r = 1 .. n_rfe - 1
    knuckle                                              q~(4) = psi4

Joint k has a constant ``origin`` (the transform from the frame after joint k-1 to joint k's frame at
q_k = 0) followed by its motion: a rotation about, or a translation along, one axis (x, y or z) of that
frame.  The world transform of the frame after joint k is therefore
``T_k = T_{k-1} @ origin_k @ motion_k(q_k)``; a body rigidly attached to that frame has ``T^(l) = T_k``.
A described joint about another unit axis a gets the frame R_a (R_a z = a) appended to its origin, and what
its link carries (bodies, points, the next origin) is expressed in that frame, so the chain moves exactly as
described.  Bodies without mass (the intermediate frames of multi-axis joints) do not appear.

Springs are linear in q: E_p,spring = 1/2 q^T K q, with K holding the support springs of the paper,
sum_s U^(sup,s)T S^(sup,s) U^(sup,s) (the linearised form printed in the paper), the RFE springs S^(l) of the
flexible links and the joint springs.  Dampers: D = beta_sup K_sup + sum_l beta_l K_l + diag(joint dampers).
The ``flexible`` variant has each flexible link's ``rfe_count`` elements (24 DOF for the paper's crane with
its 6), the ``rigid`` variant one element per flexible link (9 DOF for the paper's).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .description import (
    BASE,
    BASE_JOINTS,
    CraneDescription,
    LinkDescription,
    PointOnLink,
)
from .description import (
    PRISMATIC as PRISMATIC_JOINT,
)
from .parameters import RigidBody, SupportSpring
from .rfe import discretise_beam

PRISMATIC = 0
REVOLUTE = 1
AXES = {"x": 0, "y": 1, "z": 2}
VARIANTS = ("flexible", "rigid")
RFE_AXES = (2, 1, 0)
"""The axes of the RFE angles of a spring-damping element, in the order of :mod:`.rfe`: psi about z (bending in
the beam's x-y plane), theta about y (in its x-z plane), phi about x (torsion)."""
RFE_NAMES = {"y": ("bend_vertical", "bend_lateral", "twist"), "z": ("bend_lateral", "bend_vertical", "twist")}
"""The names of those angles by the beam's vertical axis (:class:`~.description.Beam`): with y up (the paper's
boom) psi bends it in the vertical (luffing) plane, with z up theta does."""


@dataclass(frozen=True)
class Joint:
    """One generalized coordinate: ``kind`` PRISMATIC or REVOLUTE along/about local ``axis``; ``limits``
    (lower, upper) where described."""

    name: str
    kind: int
    axis: int
    origin: np.ndarray
    limits: tuple[float, float] | None = None


@dataclass(frozen=True)
class Body:
    """A rigid body attached to the frame after joint ``joint``; mass properties in that frame."""

    name: str
    joint: int
    inertia: RigidBody


@dataclass(frozen=True)
class FlexibleLink:
    """A flexible link in the chain: its joint ``root`` (the frame of its first element), the indices
    ``springs`` of its RFE angles, the frame ``last`` of its last element, the beam's end ``tip`` (3,) in
    that frame [m], the index ``vertical`` (1 or 2) of its vertical axis in the link's frame and the rotation
    ``frame`` (3, 3) of its first element's chain frame in the link's frame (the identity unless the link's joint
    axis is not +x, +y or +z: :func:`axis_frame`)."""

    name: str
    root: int
    springs: np.ndarray
    last: int
    tip: np.ndarray
    vertical: int = 1
    frame: np.ndarray = field(default_factory=lambda: np.eye(3))


@dataclass(frozen=True)
class ChainModel:
    """Serial chain, springs, dampers and task indices of one crane variant.

    ``stiffness`` K = ``support_stiffness`` + ``beam_stiffness`` + the joint springs; ``damping`` D (None:
    none); ``dependent_joints`` the coordinates the task solves for (None: chosen at the start,
    :func:`crane_reference.motion.simulation.choose_dependent`); ``actuated_joints`` the joints with
    actuators; ``name`` the robot's."""

    variant: str
    joints: tuple[Joint, ...]
    bodies: tuple[Body, ...]
    end_effector_joint: int
    end_effector_point: np.ndarray
    gravity: float
    stiffness: np.ndarray
    support_stiffness: np.ndarray
    beam_stiffness: np.ndarray
    drive_joint: int
    dependent_joints: tuple[int, ...] | None
    initial_q: np.ndarray
    damping: np.ndarray | None = None
    actuated_joints: tuple[str, ...] = ()
    flexible_links: tuple[FlexibleLink, ...] = ()
    name: str = "crane"

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def index(self, name: str) -> int:
        """Index of the coordinate called ``name``."""
        return self.joint_names.index(name)

    @property
    def damping_matrix(self) -> np.ndarray:
        """D (n, n) [N m s/rad, N s/m]; zero where the model has no dampers."""
        return np.zeros((self.dof, self.dof)) if self.damping is None else self.damping


def homogeneous(rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 homogeneous transformation [[R, p], [0, 1]]."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def rotation(axis: int, angle: float) -> np.ndarray:
    """Elementary rotation matrix about local axis 0, 1, 2 (x, y, z)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def support_stiffness(supports: tuple[SupportSpring, ...]) -> np.ndarray:
    """6x6 stiffness of the base: sum over springs of U^T S U with the paper's linearised

    U = [[1, 0, 0, -y,  z,  0],
         [0, 1, 0,  x,  0, -z],
         [0, 0, 1,  0, -x,  y]]   acting on q~(1) = (x, y, z, psi, theta, phi).
    """
    K = np.zeros((6, 6))
    for spring in supports:
        x, y, z = spring.position
        U = np.array([[1, 0, 0, -y, z, 0], [0, 1, 0, x, 0, -z], [0, 0, 1, 0, -x, y]], dtype=float)
        K += U.T @ np.diag(spring.stiffness) @ U
    return K


def axis_frame(axis: np.ndarray) -> tuple[int, np.ndarray]:
    """(k, R_a): the chain axis k and the rotation R_a with R_a e_k = ``axis`` (unit).  R_a is the identity for
    +x, +y, +z; a half turn about x (-y, -z) or z (-x) for a negative one, so a beam's x axis is kept where it
    can be; for any other axis the frame (x', y', z' = axis) with x' the link's x axis (or, for an axis near x,
    its y axis) made orthogonal to the axis (Gram-Schmidt), so that it is as close to the link's frame as can
    be, without the division of Rodrigues' formula near -z."""
    for k in range(3):
        if np.array_equal(axis, np.eye(3)[k]):
            return k, np.eye(3)
        if np.array_equal(axis, -np.eye(3)[k]):
            return k, rotation(2 if k == 0 else 0, np.pi).round()
    seed = np.eye(3)[0] if abs(axis[0]) < 0.9 else np.eye(3)[1]
    x = seed - (seed @ axis) * axis
    x /= np.linalg.norm(x)
    return 2, np.column_stack((x, np.cross(axis, x), axis))


def transformed_body(body: RigidBody, R: np.ndarray) -> RigidBody:
    """``body`` expressed in a frame rotated by R from its own (same origin)."""
    if np.array_equal(R, np.eye(3)):
        return body
    return RigidBody(body.mass, R.T @ body.center_of_mass, R.T @ body.inertia @ R)


class _Attachment:
    """Where the next link hangs: the chain frame index, and the transform from the described parent frame
    (a link's frame, or its undeformed beam frame) to that chain frame."""

    def __init__(self, frame: int, transform: np.ndarray):
        self.frame, self.transform = frame, transform

    def origin(self, origin: np.ndarray) -> np.ndarray:
        """A transform given in the parent's described frame, in the chain frame."""
        return origin if np.array_equal(self.transform, np.eye(4)) else self.transform @ origin

    def point(self, point: np.ndarray) -> np.ndarray:
        return point if np.array_equal(self.transform, np.eye(4)) else (self.transform @ np.append(point, 1.0))[:3]


def chain_order(links: Sequence[LinkDescription]) -> tuple[LinkDescription, ...]:
    """``links`` from the base out (each link's parent the one before it); ValueError naming the links where
    they are not one serial chain."""
    children: dict[str | None, list[str]] = {}
    for link in links:
        children.setdefault(link.parent, []).append(link.name)
    by_name = {link.name: link for link in links}
    order: list[LinkDescription] = []
    parent: str | None = None
    while parent in children:
        if len(children[parent]) > 1:
            raise ValueError(f"links {', '.join(children[parent])} all hang on {parent or BASE!r}: the crane must be "
                             "one serial chain (each link the parent of at most one other)")
        parent = children[parent][0]
        order.append(by_name[parent])
        if len(order) > len(by_name):
            break
    if len(order) != len(by_name):
        missing = [name for name in by_name if name not in {link.name for link in order}]
        raise ValueError(f"links {', '.join(missing)} do not hang on the base through a chain of parents (a loop, or "
                         "a parent that is no link)")
    return tuple(order)


def build_model(description: CraneDescription, variant: str = "flexible") -> ChainModel:
    """Chain model of the crane; ``variant`` is ``"flexible"`` (each beam's ``rfe_count`` elements) or
    ``"rigid"`` (each beam one element)."""
    if variant not in VARIANTS:
        raise ValueError(f"model variant = {variant!r}: must be one of {', '.join(VARIANTS)}")
    joints: list[Joint] = []
    bodies: list[Body] = []
    initial: list[float] = []
    spring_diagonal: list[float] = []  # beam and joint springs, per coordinate
    damper_diagonal: list[float] = []  # joint dampers, per coordinate
    beta_diagonal: list[float] = []  # the beams' Rayleigh beta, per coordinate
    flexible: list[FlexibleLink] = []
    attachments: dict[str | None, _Attachment] = {}
    frames: dict[str, np.ndarray] = {}  # per link: R_a of its joint (points in the link frame -> chain frame)

    def add(joint: Joint, value: float = 0.0, spring: float = 0.0, damper: float = 0.0, beta: float = 0.0) -> int:
        joints.append(joint)
        initial.append(value)
        spring_diagonal.append(spring)
        damper_diagonal.append(damper)
        beta_diagonal.append(beta)
        return len(joints) - 1

    base = description.base
    if base is not None:
        for name, (kind, axis) in zip(BASE_JOINTS, ((PRISMATIC, 0), (PRISMATIC, 1), (PRISMATIC, 2), (REVOLUTE, 2),
                                                    (REVOLUTE, 1), (REVOLUTE, 0)), strict=True):
            add(Joint(name, kind, axis, np.eye(4)))
        bodies.append(Body("base", len(joints) - 1, base.body))
    attachments[None] = _Attachment(len(joints) - 1, np.eye(4))

    for link in chain_order(description.links):
        described = link.joint
        parent = attachments[link.parent]
        k, R = axis_frame(np.asarray(described.axis, dtype=float))
        origin = parent.origin(described.origin)
        if not np.array_equal(R, np.eye(3)):
            origin = origin @ homogeneous(R)
        kind = PRISMATIC if described.kind == PRISMATIC_JOINT else REVOLUTE
        root = add(Joint(described.name, kind, k, origin, described.limits), described.initial,
                   described.stiffness, described.damping)
        frames[link.name] = R
        if link.beam is None:
            if link.body is not None:  # a URDF link may carry no mass
                bodies.append(Body(link.name, root, transformed_body(link.body, R)))
            attachments[link.name] = _Attachment(root, homogeneous(R.T))
            continue
        beam = link.beam
        count = beam.rfe_count if variant == "flexible" else 1
        elements = discretise_beam(beam.length, count, beam.youngs_modulus, beam.shear_modulus, beam.density,
                                   beam.section)
        bodies.append(Body(f"{link.name}_rfe0", root, transformed_body(elements.bodies[0], R)))
        springs = []
        for r in range(1, count):
            at_spring = homogeneous(translation=(elements.lengths[r - 1], 0.0, 0.0))
            if r == 1 and not np.array_equal(R, np.eye(3)):
                at_spring = homogeneous(R.T) @ at_spring
            for suffix, axis, s in zip(RFE_NAMES[beam.vertical_axis], RFE_AXES, elements.spring_stiffness[r - 1],
                                       strict=True):
                springs.append(add(Joint(f"{link.name}_sde{r}_{suffix}", REVOLUTE, axis,
                                         at_spring if axis == 2 else np.eye(4)), 0.0, s, 0.0, beam.damping))
            bodies.append(Body(f"{link.name}_rfe{r}", len(joints) - 1, elements.bodies[r]))
        last = len(joints) - 1
        # the described frame seen from the last element's: back along the beam by all but the last element
        back = homogeneous(translation=(elements.lengths[-1] - beam.length, 0.0, 0.0)) if count > 1 else np.eye(4)
        to_last = back if count > 1 else homogeneous(R.T)
        attachments[link.name] = _Attachment(last, to_last)
        flexible.append(FlexibleLink(link.name, root, np.array(springs, dtype=np.int64), last,
                                     np.array([elements.lengths[-1], 0.0, 0.0]) if count > 1 else
                                     R.T @ np.array([beam.length, 0.0, 0.0]), AXES[beam.vertical_axis], R))

    def placed(point: PointOnLink) -> tuple[int, np.ndarray]:
        attachment = attachments[point.link]
        return attachment.frame, attachment.point(np.asarray(point.point, dtype=float))

    ee_joint, ee_point = placed(description.end_effector)
    if description.payload > 0.0:
        frame, at = placed(description.payload_at or description.end_effector)
        bodies.append(Body("payload", frame, RigidBody(description.payload, at, np.zeros((3, 3)))))

    n = len(joints)
    K_support, K_beam = np.zeros((n, n)), np.zeros((n, n))
    D = np.zeros((n, n))
    if base is not None:
        K_support[:6, :6] = support_stiffness(base.supports)
        D += base.damping * K_support
    is_beam = np.zeros(n, dtype=bool)
    for link in flexible:
        is_beam[link.springs] = True
    diagonal = np.array(spring_diagonal)
    K_beam[np.diag_indices(n)] = np.where(is_beam, diagonal, 0.0)
    K_joint = np.diag(np.where(is_beam, 0.0, diagonal))
    D += np.diag(np.array(beta_diagonal)) @ K_beam + np.diag(damper_diagonal)
    names = [j.name for j in joints]
    return ChainModel(
        variant=variant,
        joints=tuple(joints),
        bodies=tuple(bodies),
        end_effector_joint=ee_joint,
        end_effector_point=ee_point,
        gravity=description.gravity,
        stiffness=K_support + K_beam + K_joint,
        support_stiffness=K_support,
        beam_stiffness=K_beam,
        drive_joint=names.index(description.drive_joint),
        dependent_joints=(None if description.dependent is None
                          else tuple(names.index(j) for j in description.dependent)),
        initial_q=np.array(initial),
        damping=D if np.any(D) else None,
        actuated_joints=tuple(description.actuated),
        flexible_links=tuple(flexible),
        name=description.name,
    )
