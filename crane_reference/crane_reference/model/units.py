"""Units shared by every layer."""

NANOSECONDS = 10**9
"""Nanoseconds per second: stamps and clock readings are integers of nanoseconds."""
