"""The floor under ``stream/`` and ``control/`` (and what the ROS adapters share with them): health levels and
start-up failures (:mod:`.health`), threads' names and timing (:mod:`.threads`).  It imports nothing of the
package."""
