"""The integrator steps the package uses by default [s].

The online reference (the node, ``node_stream``, :class:`~crane_reference.motion.simulation.MotionStepper`,
the closed-loop plant) steps every millisecond, what a 1 kHz stream and its cost allow.  The offline runs
(:func:`~crane_reference.motion.simulation.simulate`, ``crane-reference simulate`` and ``analyze``, the
studies) step at :data:`ANALYSIS_STEP`, where benchmarks/bench_accuracy.py shows the accuracy targets met
(the 40-250 Hz vibration within 10 % of the converged run's, the controller-band error within 5e-5); at
1 ms it shows the luffing vibration after the internal-resonance passage off by more, and
``--only sensitivity`` how that compares with the model's own sensitivity to its parameters (README).
"""

ONLINE_STEP = 1e-3
"""[s]: the step of the online reference and of the closed-loop plant."""

ANALYSIS_STEP = 2.5e-4
"""[s]: the step of the offline runs, the simulations and studies the package reports vibration from."""
