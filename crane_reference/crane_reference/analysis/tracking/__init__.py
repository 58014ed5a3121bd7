"""Closed-loop runs of the actuated crane following the reference (controller design on the reference)."""
