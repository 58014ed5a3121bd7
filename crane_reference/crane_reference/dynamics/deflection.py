"""The boom tip's deflection relative to its rigid chord, in the frame of the first boom element (the frame
after the luff joint: x along the unbent boom, y up in the luffing plane, z along the luff axis):

    w = R_0^T (r_tip(q) - r_tip(q with every RFE angle set to 0)),

r_tip the origin of the knuckle frame; R_0 is the same in both terms because the RFE joints come after the
luff joint.  w_y is the deflection in the luffing plane, w_z the horizontal one, w_x the (second-order)
shortening.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..model.chain import ChainModel
from .kinematics import forward_kinematics
from .structures import ChainData


def rfe_indices(model: ChainModel, suffix: str = "") -> np.ndarray:
    """Indices of the boom's RFE angles (all, or those whose name ends with ``suffix``)."""
    return np.array([k for k, name in enumerate(model.joint_names)
                     if name.startswith("boom_sde") and name.endswith(suffix)], dtype=np.int64)


class TipDeflection:
    """w of the module docstring for the chain of ``model`` (``chain`` is ``CraneDynamics.chain``)."""

    def __init__(self, model: ChainModel, chain: ChainData):
        self._arguments = (rfe_indices(model), model.index("boom_luff"), model.index("knuckle"), chain.kinds,
                           chain.axes, chain.origins)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """w (N, 3) [m] for q (N, n) (one row for q (n,))."""
        return _deflections(np.ascontiguousarray(np.atleast_2d(q), dtype=float), *self._arguments)


def boom_tip_deflection(model: ChainModel, chain: ChainData, q: np.ndarray) -> np.ndarray:
    """w (N, 3) [m] for q (N, n) (one row for q (n,)), see the module docstring; ``chain`` is
    ``CraneDynamics.chain``."""
    return TipDeflection(model, chain)(q)


@njit(cache=True, nogil=True)
def _deflections(q, rfe, luff, tip, kinds, axes, origins):
    out = np.empty((q.shape[0], 3))
    for i in range(q.shape[0]):
        T, _ = forward_kinematics(q[i], kinds, axes, origins)
        chord = q[i].copy()
        chord[rfe] = 0.0
        T0, _ = forward_kinematics(chord, kinds, axes, origins)
        for a in range(3):  # R_0^T (r_tip - r_tip of the chord)
            out[i, a] = sum([T[luff, b, a] * (T[tip, b, 3] - T0[tip, b, 3]) for b in range(3)])
    return out
