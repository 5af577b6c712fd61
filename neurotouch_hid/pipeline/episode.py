"""One gesture type per gesture episode, committed once the fingers are found (not in the paper;
docs/method.md, "Episode vote")."""

from __future__ import annotations

import math

from neurotouch_hid.core.estimate import GestureType

#: How long (us) an episode that shows one contact stays undecided: a second finger may land up
#: to ~100 ms after the first and is seen a window or two later (docs/method.md, "Episode vote").
FIRST_FINGER_US = 90_000
#: A lone contact whose gel moves nowhere against its drag by ``QUIET_MM`` or more ends its wait
#: this much (us) sooner: one window of the pipeline's 100 Hz. A second finger dragging another way
#: moves the gel against the first's drag (``counter_drag.py``) by the window its gel has moved
#: 0.3 mm, and the contact step finds it a median 5-7 ms after that: one window later. Two windows
#: sooner commit the lone first fingers of late pinches, zooms and twists as push
#: (docs/method.md, "A lone contact's field").
QUIET_LEAD_US = 10_000
#: ... below this counter-motion (mm) the field is one finger's: the labels' own tolerance for a
#: gel at rest, above the 0-0.06 mm a lone finger's field shows against its drag on most gels
#: (docs/method.md, "A lone contact's field").
QUIET_MM = 0.1
#: Within this time (us) of the onset one correction is allowed (libinput's 300 ms).
CORRECTION_US = 300_000
#: Below this intensity (mm) an undecided window answers the vote so far: it is below every dead zone
#: and press threshold of the built-in profiles (the lowest: ``spacecraft``'s triggers, 0.4 mm),
#: so nothing is felt, and the onset is not delayed (docs/method.md, "Episode vote").
PROVISIONAL_MM = 0.4
#: Once the type is committed, a window at or above this intensity (mm) that sees two contacts or
#: more votes twice: one contact is what a multi-finger gesture shows when its fingers merge or one
#: is missed, never the reverse. Below it, in an attack's first 0.15-0.6 mm, a flickering light
#: makes the contact count jump between 1 and 3 window after window
#: (docs/method.md, "Episode vote").
COUNTED_MM = 0.8
#: A committed episode whose intensity has fallen below this share of its peak (the fingers mostly
#: gone: a release, or a creeping gel's tail still read as the gesture) ...
REPRESS_SHARE = 0.5
#: ... and has risen again by this much (mm) above its lowest since, in a window of another type
#: that sees two contacts or more, is a new press: a new episode begins at that window
#: (docs/method.md, "Episode vote"). Above the ~0.25 mm a tracked tail rises between two APS
#: frames' corrections; one contact is left out, as its intensity jumps where fingers merge.
REPRESS_MM = 0.3
#: At or above this intensity (mm), well above every dead zone of the built-in profiles, a type
#: answered at this intensity in the window before changes to another only when two windows in a
#: row read it (otherwise it holds): one window of another type inside a firm gesture is
#: a misreading (a finger's field merging for a window, a single ``none`` restarting the episode),
#: and at 4-9 mm it moves an output for a game frame (docs/method.md, "Episode vote").
FIRM_MM = 2.0
#: A type answered within this time (us) before still holds the next window at or above
#: ``FIRM_MM``, across a ``none`` window that restarted the episode: one APS frame period. For as
#: long after the window that found a lone first finger's next finger, a window that sees fewer
#: contacts again and reads another type casts no vote: the finger just found is missed, not gone.
FIRM_GAP_US = 40_000


class EpisodeVote:
    """One gesture type per gesture episode (docs/method.md, "Episode vote").

    The windows from a gesture's onset (its first window with a gesture) to its end (the next
    ``none`` window) form an episode. While its windows have shown at most one contact, for less
    than ``first_finger_us``, the episode is *undecided*: a multi-finger gesture whose first finger
    leads reads as a one-finger push until the next finger moves the gel (paper, "Results"). An
    undecided window whose intensity is below ``provisional_mm`` (too weak for a profile to map
    it) answers the vote so far (below); from there on it answers ``none`` (no output for the
    mapper). The type is committed at the first window at or above ``provisional_mm`` that sees
    two contacts or more, or once one contact has held for ``first_finger_us`` (``quiet_lead_us``
    less in a window whose gel moves nowhere against the contact's drag: one finger's field,
    :meth:`update`'s ``counter_mm``): the type with the most intensity-weighted votes (mm) since
    the contact count last changed. A window below
    ``provisional_mm`` commits nothing whatever its count (a gel that has barely moved shows
    spurious contacts: one such window committing push on three contacts made a twist's lone
    first finger felt as push), and its count does not restart the one-contact wait either: that
    runs from the last change of the count among the windows at or above ``provisional_mm``, for
    the first of them from the onset (a fast push whose first windows show 2-3 spurious contacts
    waits no longer than one without them). Within ``first_finger_us`` of the onset, a window at or above
    ``counted_mm`` that reads push on two contacts or more commits only when the window before saw
    two or more too (below it a flickering light's count jumps, and such a window commits at once,
    as before): the fingers
    of a twist, pinch or zoom sliding together for a moment read push, on contacts the next
    window may not see (a two-finger push is answered one window later).

    Once the episode has been committed on two contacts or more at or above ``counted_mm``, or a
    window of the committed type has seen them there, a window on one contact of another type
    answers the committed type and casts no vote: a multi-finger gesture shows one contact when a
    finger is missed or its fingers merge, never the reverse.

    Once committed, each window adds its intensity to its own type's votes, twice when it sees two
    contacts or more at or above ``counted_mm``, and the answer changes only when another type
    outweighs it, with two exceptions. Within ``correction_us`` of the onset, or later while no
    window of the episode has reached ``counted_mm`` (a slow attack nobody has felt yet), once per
    episode, a window that sees more contacts than every earlier window and reads another type is
    answered at once and the votes restart from it (the fingers seen before were fewer than the
    gesture has; such a window of the committed type restarts the votes too). And a window of
    another type that sees two contacts or more, whose intensity has risen ``repress_mm`` above
    the lowest since the episode's peak, that lowest below ``repress_share`` of the peak, begins
    a new episode (a new press after the fingers had mostly left: a creeping gel's release tail
    can still be read as the last gesture when the next one begins in it).

    A window that, within ``FIRM_GAP_US`` after the one correction found the next finger of an
    episode that had shown one contact, sees fewer contacts than that window and reads another
    type, answers the committed type and casts no vote (a finger just found and missed for a
    window is still there).

    Whatever the above answers, a type answered at or above ``firm_mm`` within ``FIRM_GAP_US``
    before (in this episode or the one a ``none`` window just ended) changes, in a window at or
    above ``firm_mm``, to another type only when that window and the one before it both read that
    type; otherwise the type before holds (an undecided window too).

    Args:
        first_finger_us: how long one contact alone stays undecided (us, >= 0).
        correction_us: how long after the onset the one correction may come (us, >= 0).
        provisional_mm: below this intensity (mm, >= 0) an undecided window answers the vote so far.
        counted_mm: from this intensity (mm, >= 0) on, a committed episode's window that sees two
            contacts or more votes twice.
        repress_share: share of the episode's peak intensity (0..1) its intensity must have fallen
            below before a new press can begin a new episode.
        repress_mm: how far (mm, > 0) above its lowest since the peak a window of another type that
            sees two contacts or more must rise to begin one.
        firm_mm: from this intensity (mm, >= 0; inf: never) on, a type answered the window before
            changes only when two windows in a row say so.
        quiet_lead_us: how much sooner (us, >= 0) one contact commits in a window whose field is
            one finger's.
        quiet_mm: below this counter-motion (mm, >= 0) a window's field is one finger's.
    """

    def __init__(
        self,
        first_finger_us: int = FIRST_FINGER_US,
        correction_us: int = CORRECTION_US,
        provisional_mm: float = PROVISIONAL_MM,
        counted_mm: float = COUNTED_MM,
        repress_share: float = REPRESS_SHARE,
        repress_mm: float = REPRESS_MM,
        firm_mm: float = FIRM_MM,
        quiet_lead_us: int = QUIET_LEAD_US,
        quiet_mm: float = QUIET_MM,
    ) -> None:
        self.first_finger_us = first_finger_us
        self.correction_us = correction_us
        self.provisional_mm = provisional_mm
        self.counted_mm = counted_mm
        self.repress_share = repress_share
        self.repress_mm = repress_mm
        self.firm_mm = firm_mm
        self.quiet_lead_us = quiet_lead_us
        self.quiet_mm = quiet_mm
        self._held: GestureType | None = None  # the type last answered at or above firm_mm ...
        self._held_us = 0  # ... when
        self._quiet = False  # the window's field is one finger's (update's counter_mm)
        self.reset()

    def reset(self) -> None:
        """End the episode (a ``none`` or resting window, or a restart)."""
        self._votes: dict[GestureType, float] = {}
        self._decision: GestureType | None = None
        self._onset_us = 0
        self._count = -1
        self._count_since_us = 0
        self._trusted = -1  # the contact count of the last window at or above provisional_mm ...
        self._trusted_since_us = 0  # ... since when (the onset for the first such window)
        self._most_contacts = -1
        self._corrected = False
        self._peak = 0.0  # the episode's highest intensity (mm) ...
        self._low = math.inf  # ... and its lowest since (mm)
        self._said = GestureType.NONE  # the window before's own type
        self._found = 0  # the contacts of the window that found a lone first finger's next finger ...
        self._found_us = 0  # ... and when
        self._multi = False  # the type was committed on two contacts or more (or corrected to them)

    @property
    def undecided(self) -> bool:
        """No type committed in this episode yet (a window of one contact may read the field,
        :meth:`update`'s ``counter_mm``)."""
        return self._decision is None

    def update(
        self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int, counter_mm: float = math.inf
    ) -> GestureType:
        """The answer after one window ending at ``t_us`` (us, increasing) of type ``gesture``,
        intensity ``intensity_mm`` (mm, >= 0) and ``n_contacts`` contact points: the committed
        type; while undecided, the vote so far below ``provisional_mm`` and ``NONE`` at or above
        it; at or above ``firm_mm``, the type answered before until two windows in a row answer
        another. A ``NONE`` window ends the episode and is returned as is. ``counter_mm``: how
        far the gel moves against a lone contact's drag (mm, ``counter_drag.counter_drag_mm``;
        inf: not read), below ``quiet_mm`` the one-contact wait ends ``quiet_lead_us`` sooner."""
        if gesture is GestureType.NONE:  # as cheap as before for a resting window
            self.reset()
            return gesture
        said_before = self._said
        self._quiet = counter_mm < self.quiet_mm
        answer = self._vote(gesture, intensity_mm, n_contacts, t_us)
        self._said = gesture
        held = self._held
        if answer is GestureType.NONE:
            if held is not None and intensity_mm >= self.firm_mm and t_us - self._held_us <= FIRM_GAP_US:
                self._held_us = t_us  # undecided inside a firm type (an episode restarted): it holds
                return held
            return answer
        if (
            held is not None
            and answer is not held
            and intensity_mm >= self.firm_mm
            and t_us - self._held_us <= FIRM_GAP_US
            and not (gesture is answer and said_before is answer)
        ):
            answer = held  # another type, not said by two windows in a row: the type before holds
        if intensity_mm >= self.firm_mm:
            self._held, self._held_us = answer, t_us
        return answer

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        """:meth:`update` of a window with a gesture, without the firm type."""
        if (
            n_contacts < self._found
            and t_us - self._found_us <= FIRM_GAP_US
            and gesture is not self._decision
            and self._decision is not None
        ):
            return self._decision  # the finger just found, missed for a window: no vote
        if (
            self._decision is not None
            and gesture is not self._decision
            and n_contacts >= 2
            and self._low < self.repress_share * self._peak
            and intensity_mm - self._low >= self.repress_mm
        ):
            self.reset()  # a new press: a new episode from this window
        unfelt = self._peak < self.counted_mm  # no window of the episode has reached a dead zone yet
        if intensity_mm >= self._peak:
            self._peak, self._low = float(intensity_mm), math.inf
        else:
            self._low = min(self._low, float(intensity_mm))
        if self._most_contacts < 0:
            self._onset_us = t_us
        count_before = self._count
        if n_contacts != self._count:
            self._count, self._count_since_us = n_contacts, t_us
            if self._decision is None:
                self._votes = {}
        weight = max(float(intensity_mm), 1e-6)
        if self._decision is None:
            weak = intensity_mm < self.provisional_mm  # its contact count is not yet to be trusted
            self._most_contacts = max(self._most_contacts, 0 if weak else n_contacts)
            self._votes[gesture] = self._votes.get(gesture, 0.0) + weight
            if weak:
                return max(self._votes, key=self._votes.get)
            if n_contacts != self._trusted:
                self._trusted_since_us = self._onset_us if self._trusted < 0 else t_us
                self._trusted = n_contacts
            wait = self.first_finger_us - (self.quiet_lead_us if self._quiet else 0)
            if n_contacts <= 1 and t_us - self._trusted_since_us < wait:
                return GestureType.NONE
            if (
                gesture is GestureType.PUSH
                and count_before < 2 <= n_contacts
                and intensity_mm >= self.counted_mm
                and t_us - self._onset_us < self.first_finger_us
            ):
                return GestureType.NONE  # several contacts read push, not seen the window before
            self._decision = max(self._votes, key=self._votes.get)
            self._multi = n_contacts >= 2 and intensity_mm >= self.counted_mm
            return self._decision
        if self._multi and n_contacts <= 1 and gesture is not self._decision:
            return self._decision  # a finger of a multi-finger episode merged or missed: no vote
        if n_contacts > self._most_contacts and (t_us - self._onset_us <= self.correction_us or unfelt):
            if gesture is not self._decision and not self._corrected:
                if self._most_contacts <= 1:  # the lone first finger's next finger
                    self._found, self._found_us = n_contacts, t_us
                self._decision, self._corrected, self._votes = gesture, True, {}
            elif gesture is self._decision:
                self._votes = {}  # the votes cast on fewer fingers than the gesture has no longer count
        if n_contacts >= 2 and intensity_mm >= self.counted_mm:
            weight *= 2.0
            self._multi = self._multi or gesture is self._decision
        self._most_contacts = max(self._most_contacts, n_contacts)
        self._votes[gesture] = self._votes.get(gesture, 0.0) + weight
        if self._votes.get(self._decision, 0.0) < max(self._votes.values()):
            self._decision = max(self._votes, key=self._votes.get)
        return self._decision
