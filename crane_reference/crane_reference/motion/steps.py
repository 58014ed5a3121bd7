"""The integrator steps the package uses by default [s].

benchmarks/bench_accuracy.py measures each step against the converged run.  The targets: the
controller-band error (the error low-passed at 10 Hz) within 5e-5 rad / m, the 40-250 Hz vibration within
10 % of the converged run's before the internal-resonance passage, and after it no farther from the
converged run than the model itself moves with its payload changed by 0.5 % (``--only sensitivity``).
:data:`ONLINE_STEP`, the online reference's default, is the largest of the steps measured there (1, 0.5 and
0.25 ms) that meets them.  The offline runs
(:func:`~crane_reference.motion.simulation.simulate`, ``crane-reference simulate`` and ``analyze``, the
studies) step at :data:`ANALYSIS_STEP`, where the vibration stays within 10 % of the converged run's
throughout.  The closed-loop plant of ``crane-reference track`` steps at :data:`PLANT_STEP`, one period of
its 1 kHz controller.
"""

ONLINE_STEP = 5e-4
"""[s]: the default step of the online reference (the node, ``node_stream``, ``MotionStepper``)."""

ANALYSIS_STEP = 2.5e-4
"""[s]: the step of the offline runs, the simulations and studies the package reports vibration from."""

PLANT_STEP = 1e-3
"""[s]: the step of the closed-loop plant (one period of the default 1 kHz controller)."""
