"""A clamped-free uniform beam as a chain (the modal tests' analytic case)."""

from __future__ import annotations

import numpy as np

from crane_reference.model.chain import AXES, REVOLUTE, Body, ChainModel, Joint, homogeneous
from crane_reference.model.parameters import BeamSection
from crane_reference.model.rfe import discretise_beam


def cantilever_model(length: float, rfe_count: int, youngs_modulus: float, shear_modulus: float, density: float,
                     section: BeamSection, plane: str = "vertical", gravity: float = 0.0) -> ChainModel:
    """A clamped-free uniform beam from :func:`discretise_beam`: element 0 is clamped, elements 1 .. n-1
    hang on one bending spring each, about z (``plane="vertical"``, s = E I_z / dl) or about y
    (``"lateral"``, s = E I_y / dl); the beam lies along x at q = 0."""
    axis, column = {"vertical": ("z", 0), "lateral": ("y", 1)}[plane]
    beam = discretise_beam(length, rfe_count, youngs_modulus, shear_modulus, density, section)
    n = rfe_count - 1
    joints = tuple(Joint(f"sde{r}_bend", REVOLUTE, AXES[axis], homogeneous(translation=(beam.lengths[r - 1], 0.0, 0.0)))
                   for r in range(1, rfe_count))
    bodies = tuple(Body(f"beam_rfe{r}", r - 1, beam.bodies[r]) for r in range(1, rfe_count))
    K = np.diag(beam.spring_stiffness[:, column])
    return ChainModel(variant="cantilever", joints=joints, bodies=bodies, end_effector_joint=n - 1,
                      end_effector_point=np.array([beam.lengths[-1], 0.0, 0.0]), gravity=gravity, stiffness=K,
                      support_stiffness=np.zeros_like(K), beam_stiffness=K, drive_joint=0, dependent_joints=(),
                      initial_q=np.zeros(n))
