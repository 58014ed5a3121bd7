"""Rigid finite element (RFE) discretisation of a uniform beam.

Following Wittbrodt, Adamiec-Wojcik and Wojciech, *Dynamics of Flexible Multibody Systems: Rigid
Finite Element Method* (Springer 2006), a beam of length L is first cut into m = n_rfe - 1 equal
segments of length dl = L / m.  A spring-damping element (sde) sits at the middle of each segment and
the rigid elements (rfe) lie between them: the two end elements have length dl/2, the inner ones dl.
Each sde carries three rotational springs, in the element frame (x along the beam axis):

* psi   about z (bending in the beam's x-y plane):  s_psi   = E I_z / dl
* theta about y (bending in the beam's x-z plane):  s_theta = E I_y / dl
* phi   about x (torsion):                           s_phi   = G J   / dl

and the relative rotation of element r with respect to element r-1 is Rz(psi) Ry(theta) Rx(phi)
(ZYX order, as for the base in eq. (1)).  With n_rfe = 1 the beam is a single rigid body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parameters import BeamSection, RigidBody


@dataclass(frozen=True)
class RfeBeam:
    """Elements and springs of a discretised beam.

    ``lengths[r]`` is the length of element r, whose frame has its origin at the element's start on
    the beam axis; ``bodies[r]`` its mass properties in that frame; ``spring_stiffness[r - 1]`` the
    (s_psi, s_theta, s_phi) of the sde between elements r - 1 and r [N m/rad].
    """

    lengths: np.ndarray
    bodies: tuple[RigidBody, ...]
    spring_stiffness: np.ndarray


def segment_body(length: float, density: float, section: BeamSection) -> RigidBody:
    """Mass properties of a uniform straight beam segment [0, length] along x.

    m = rho A l, centre at (l/2, 0, 0); about the centre I_xx = rho l (I_y + I_z) (polar moment),
    I_yy = m l^2 / 12 + rho l I_y, I_zz = m l^2 / 12 + rho l I_z.
    """
    mass = density * section.area * length
    inertia = np.diag(
        [
            density * length * (section.second_moment_y + section.second_moment_z),
            mass * length**2 / 12.0 + density * length * section.second_moment_y,
            mass * length**2 / 12.0 + density * length * section.second_moment_z,
        ]
    )
    return RigidBody(mass, np.array([0.5 * length, 0.0, 0.0]), inertia)


def discretise_beam(
    length: float,
    rfe_count: int,
    youngs_modulus: float,
    shear_modulus: float,
    density: float,
    section: BeamSection,
) -> RfeBeam:
    """Cut a uniform beam into ``rfe_count`` rigid elements joined by ``rfe_count - 1`` sdes."""
    if rfe_count == 1:
        lengths = np.array([length])
        springs = np.zeros((0, 3))
    else:
        dl = length / (rfe_count - 1)
        lengths = np.full(rfe_count, dl)
        lengths[[0, -1]] = 0.5 * dl
        per_spring = np.array(
            [
                youngs_modulus * section.second_moment_z / dl,
                youngs_modulus * section.second_moment_y / dl,
                shear_modulus * section.torsion_constant / dl,
            ]
        )
        springs = np.tile(per_spring, (rfe_count - 1, 1))
    bodies = tuple(segment_body(float(lr), density, section) for lr in lengths)
    return RfeBeam(lengths, bodies, springs)
