"""Frequency bands of signals sampled at a fixed step: the controller band and the vibration above it.

A 4th-order Butterworth filter applied forward and backward (zero phase, ``scipy.signal.sosfiltfilt``):
``controller_band`` keeps what a controller follows, below :data:`CONTROLLER_BAND` Hz; ``vibration_band``
the boom's vibration, :data:`VIBRATION_BAND`.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

CONTROLLER_BAND = 10.0  # [Hz]


def controller_band(signal: np.ndarray, step: float, cutoff: float = CONTROLLER_BAND) -> np.ndarray:
    """``signal`` (first axis: samples ``step`` seconds apart) low-passed below ``cutoff`` Hz, zero phase."""
    sos = butter(4, cutoff, btype="lowpass", fs=1.0 / step, output="sos")
    return sosfiltfilt(sos, signal, axis=0)


VIBRATION_BAND = (40.0, 250.0)  # [Hz], the band of the boom's bending and torsion modes


def vibration_band(signal: np.ndarray, step: float, band: tuple[float, float] = VIBRATION_BAND) -> np.ndarray:
    """``signal`` (first axis: samples ``step`` seconds apart) band-passed to ``band`` [Hz], zero phase."""
    if not band[1] < 0.5 / step:
        raise ValueError(f"step = {step} s: the band up to {band[1]} Hz needs samples at least every "
                         f"{0.5 / band[1]:g} s")
    sos = butter(4, band, btype="bandpass", fs=1.0 / step, output="sos")
    return sosfiltfilt(sos, signal, axis=0)
