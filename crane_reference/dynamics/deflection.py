"""The boom tip's deflection relative to its rigid chord, in the frame of the first boom element (the frame
after the luff joint: x along the unbent boom, y up in the luffing plane, z along the luff axis):

    w = R_0^T (r_tip(q) - r_tip(q with every RFE angle set to 0)),

r_tip the origin of the knuckle frame; R_0 is the same in both terms because the RFE joints come after the
luff joint.  w_y is the deflection in the luffing plane, w_z the horizontal one, w_x the (second-order)
shortening.
"""

from __future__ import annotations

import numpy as np

from ..model.chain import ChainModel
from .kinematics import forward_kinematics
from .structures import ChainData


def rfe_indices(model: ChainModel, suffix: str = "") -> np.ndarray:
    """Indices of the boom's RFE angles (all, or those whose name ends with ``suffix``)."""
    return np.array([k for k, name in enumerate(model.joint_names)
                     if name.startswith("boom_sde") and name.endswith(suffix)], dtype=np.int64)


def boom_tip_deflection(model: ChainModel, chain: ChainData, q: np.ndarray) -> np.ndarray:
    """w (N, 3) [m] for q (N, n), see the module docstring; ``chain`` is ``CraneDynamics.chain``."""
    kinds, axes, origins = chain.kinds, chain.axes, chain.origins
    luff, tip = model.index("boom_luff"), model.index("knuckle")
    rfe = rfe_indices(model)
    q = np.atleast_2d(q)
    out = np.empty((len(q), 3))
    for i, qi in enumerate(q):
        T, _ = forward_kinematics(np.ascontiguousarray(qi, dtype=float), kinds, axes, origins)
        chord = qi.copy()
        chord[rfe] = 0.0
        T0, _ = forward_kinematics(chord, kinds, axes, origins)
        out[i] = T[luff, :3, :3].T @ (T[tip, :3, 3] - T0[tip, :3, 3])
    return out
