"""A flexible link's tip deflection relative to its rigid chord, in the frame of the link's first element (the
frame after the link's joint: x along the unbent beam; for the paper's boom y up in the luffing plane and z
along the luff axis):

    w = R_0^T (r_tip(q) - r_tip(q with the link's RFE angles set to 0)),

r_tip the beam's end (on its last element); R_0 is the same in both terms because the RFE joints come after
the link's joint.  w_y is the deflection in the beam's x-y plane (the luffing plane of a boom), w_z the one
across it, w_x the (second-order) shortening.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..model.chain import ChainModel, FlexibleLink
from .kinematics import forward_kinematics
from .structures import ChainData, LinkTip


def flexible_link(model: ChainModel, name: str | None = None) -> FlexibleLink:
    """The flexible link called ``name`` (by default the first, the paper's boom); ValueError if there is none."""
    for link in model.flexible_links:
        if name is None or link.name == name:
            return link
    known = ", ".join(link.name for link in model.flexible_links) or "none"
    raise ValueError(f"flexible link {name!r}: the crane's flexible links are {known}")


def link_tip(model: ChainModel, name: str | None = None) -> LinkTip:
    """The flexible link ``name``'s (default the first) :class:`~.structures.LinkTip` for :func:`deflection_at`;
    the rigid chord's (no RFE angles: w = 0) if the crane has no flexible link and ``name`` is None."""
    if name is None and not model.flexible_links:
        return LinkTip(np.empty(0, dtype=np.int64), 0, 0, np.zeros(3))
    flexible = flexible_link(model, name)
    return LinkTip(np.asarray(flexible.springs, dtype=np.int64), flexible.root, flexible.last,
                   np.asarray(flexible.tip, dtype=float))


def rfe_indices(model: ChainModel, suffix: str = "", link: str | None = None) -> np.ndarray:
    """Indices of the RFE angles of every flexible link, or of ``link``'s (all, or those whose name ends with
    ``suffix``)."""
    links = model.flexible_links if link is None else (flexible_link(model, link),)
    indices = [k for each in links for k in each.springs if model.joints[k].name.endswith(suffix)]
    return np.array(sorted(indices), dtype=np.int64)


class TipDeflection:
    """w of the module docstring for the flexible link ``link`` (default the first) of ``model`` (``chain`` is
    ``CraneDynamics.chain``), in the link's own frame, or with ``link_frame`` False in its first element's frame
    of the chain (its first link of the URDF; the same frame unless the link's joint axis is not +x, +y or +z)."""

    def __init__(self, model: ChainModel, chain: ChainData, link: str | None = None, link_frame: bool = True):
        flexible = flexible_link(model, link)
        self._arguments = (link_tip(model, flexible.name), chain.kinds, chain.axes, chain.origins)
        turned = link_frame and not np.array_equal(flexible.frame, np.eye(3))
        self._frame = flexible.frame if turned else None

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """w (N, 3) [m] for q (N, n) (one row for q (n,))."""
        w = _deflections(np.ascontiguousarray(np.atleast_2d(q), dtype=float), *self._arguments)
        return w if self._frame is None else w @ self._frame.T


def tip_deflection(model: ChainModel, chain: ChainData, q: np.ndarray, link: str | None = None) -> np.ndarray:
    """w (N, 3) [m] of the flexible link ``link`` (default the first) for q (N, n) (one row for q (n,)), see the
    module docstring; ``chain`` is ``CraneDynamics.chain``."""
    return TipDeflection(model, chain, link)(q)


@njit(cache=True, nogil=True)
def _deflections(q, tip: LinkTip, kinds, axes, origins):
    out = np.empty((q.shape[0], 3))
    for i in range(q.shape[0]):
        out[i] = deflection_at(q[i], tip, kinds, axes, origins)
    return out


@njit(cache=True, nogil=True)
def deflection_at(q, tip: LinkTip, kinds, axes, origins):
    """w (3,) [m] of the module docstring at q (n,) in the frame of the link's first element (zero if ``tip``
    has no RFE angles)."""
    w = np.zeros(3)
    if tip.springs.size == 0:
        return w
    T, _ = forward_kinematics(q, kinds, axes, origins)
    chord = q.copy()
    chord[tip.springs] = 0.0
    T0, _ = forward_kinematics(chord, kinds, axes, origins)
    last, root = tip.last, tip.root
    gap = np.empty(3)  # r_tip - r_tip of the chord
    for b in range(3):
        gap[b] = T[last, b, 3] - T0[last, b, 3] + sum([(T[last, b, c] - T0[last, b, c]) * tip.point[c]
                                                        for c in range(3)])
    for a in range(3):  # R_0^T gap
        w[a] = sum([T[root, b, a] * gap[b] for b in range(3)])
    return w
