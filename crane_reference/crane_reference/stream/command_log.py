"""Status as data: what each command of the reference server did, for diagnostics and recordings.

Per command name: when it was accepted (``{name}_accepted_s``, the publisher's clock), the stamp it takes effect at
(``{name}_stamp_s``, once publishing gives it one), the stream time of that sample (``{name}_stream_time_s``,
exact: it locates the command in a recording or an offline run) and its margin (``{name}_margin_s``: how long
before that stamp its first frame was ready; negative: samples were held, a longer lead helps); the last
restart's jump (``restart_jump_rad``, ``restart_jump_joint``).  No lock of its own: the server's is held.
"""

from __future__ import annotations

from ..model.units import NANOSECONDS
from .served import Restart
from .stamps import Stamps


class CommandLog:
    """See the module documentation."""

    def __init__(self) -> None:
        self._entries: dict[str, str] = {}
        self._awaiting: dict[str, int] = {}  # command -> its first frame, until made
        self._unstamped: dict[str, int] = {}  # command made while not publishing -> its frame, stamped at begin

    def entries(self) -> dict[str, str]:
        """A copy of the log, by entry name."""
        return dict(self._entries)

    def expect(self, name: str, k: int, stamps: Stamps) -> None:
        """Command ``name`` takes effect at frame k, made again from now on: its margin is measured once made."""
        self._entries.pop(f"{name}_margin_s", None)
        if stamps.publishing:
            self._awaiting[name] = k

    def record(self, name: str, k: int, tau: float, accepted_ns: int, stamps: Stamps) -> None:
        """Command ``name``, accepted at ``accepted_ns``, takes effect at frame k, stream time tau [s]."""
        if stamps.publishing:
            self._entries[f"{name}_stamp_s"] = f"{stamps.stamp_of(k):.6f}"
        else:  # stamped when publishing begins (:meth:`stamp_pending`)
            self._entries.pop(f"{name}_stamp_s", None)
            self._unstamped[name] = k
        self._entries[f"{name}_accepted_s"] = f"{accepted_ns / NANOSECONDS:.6f}"
        self._entries[f"{name}_stream_time_s"] = repr(tau)

    def frames_made(self, made_k: int, stamps: Stamps) -> None:
        """Frames up to ``made_k`` (excluded) are made: a command whose first frame is among them gets its margin,
        how long before that frame is due it was ready, at least."""
        for name, k in list(self._awaiting.items()):
            if not stamps.publishing:
                del self._awaiting[name]
            elif made_k > k:
                self._entries[f"{name}_margin_s"] = f"{(stamps.stamp_ns(k) - stamps.now_ns()) / NANOSECONDS:.6f}"
                del self._awaiting[name]

    def stamp_pending(self, stamps: Stamps) -> None:
        """Publishing began: the commands made before it get their stamps."""
        for name, k in self._unstamped.items():
            self._entries[f"{name}_stamp_s"] = f"{stamps.stamp_of(k):.6f}"
        self._unstamped.clear()

    def restarted(self, restart: Restart) -> None:
        self._entries.update(restart_jump_rad=f"{restart.jump:.6g}", restart_jump_joint=restart.joint)
