"""One gesture decision per gesture episode (not in the paper; docs/method.md, "Episode vote")."""

from __future__ import annotations

from neurotouch_hid.estimate import GestureType


class EpisodeVote:
    """One gesture decision per gesture episode (not in the paper; docs/method.md, "Episode vote").

    The windows from a gesture's onset (the first window with a gesture) to its end (the next
    ``none`` window) form an episode. Each window adds its intensity (mm) to the votes of its own
    type; the episode's decision is the type with the most votes so far, the window's own type on
    a tie. The first window of an episode is answered with its own type (no added latency at
    onset); a later window changes the answer only once its type outweighs the others.

    While the decision is push, a window that sees more contacts than every earlier window of the
    episode and reads another type restarts the votes from that window. A multi-finger gesture whose
    first finger leads reads as a one-finger push until the next finger moves the gel (paper,
    "Results": "multi-finger gestures often exhibit varying intensities across individual
    fingers"); those push votes were cast on fewer contacts than the gesture has, so they stop
    counting once the finger they missed is seen.
    """

    def __init__(self) -> None:
        self._votes: dict[GestureType, float] = {}
        self._decision: GestureType | None = None
        self._most_contacts = 0

    def reset(self) -> None:
        """End the episode (a ``none`` or resting window, or a restart)."""
        self._votes = {}
        self._decision = None
        self._most_contacts = 0

    def update(self, gesture: GestureType, intensity_mm: float, n_contacts: int = 0) -> GestureType:
        """The decision after one window of type ``gesture`` with intensity ``intensity_mm`` (mm,
        >= 0) and ``n_contacts`` contact points (0-3);
        ``NONE`` ends the episode and is returned as is."""
        if gesture is GestureType.NONE:
            self.reset()
            return gesture
        if self._decision is GestureType.PUSH and gesture is not GestureType.PUSH and n_contacts > self._most_contacts:
            self._votes = {}
        self._most_contacts = max(self._most_contacts, n_contacts)
        self._votes[gesture] = self._votes.get(gesture, 0.0) + max(float(intensity_mm), 1e-6)
        best = max(self._votes.values())
        self._decision = gesture if self._votes[gesture] == best else max(self._votes, key=self._votes.get)
        return self._decision
