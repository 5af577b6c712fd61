"""The pipeline's fit of a moving window (paper, "Contact Point Detection" and "Gesture
Classification and Intensity Prediction"; docs/method.md, "Gel motion", "Camera model", "Contacts",
"Gesture" and "A lone contact's field"): what :class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`
(which composes it with the window and frame paths) computes for a window whose markers moved.

The gel's motion in its mount is removed, the contacts are found on the positions undistorted by
the camera model and put back in the image, the gesture's similarity and intensity are read about
them, and a learned classifier gives the type. The positions the contact step read stay with its
contacts, so that the episode vote's counter-drag of a lone contact reads the same ones.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline.contacts import Contacts, detect_contacts
from neurotouch_hid.pipeline.contacts_bump import maxima_pushed_out
from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours
from neurotouch_hid.pipeline.counter_drag import counter_drag_mm
from neurotouch_hid.pipeline.episode import PROVISIONAL_MM
from neurotouch_hid.pipeline.gel_motion import estimate_gel_motion, rim_markers
from neurotouch_hid.pipeline.gesture import GestureResult, estimate_gesture
from neurotouch_hid.pipeline.learned import gesture_features, learned_gesture

__all__ = ["FitPath"]


class FitPath:
    """The fit half of the gesture pipeline. A base of
    :class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, which provides ``config``,
    ``sensor``, the press's state (``_long_press``), what the episode vote's window was fitted on
    (``_voted``), the per-rest tables (``_of_rest``) and the stage clock (``_clock``, ``_record``).

    Attributes:
        _fitted_on_gel: the last fit's positions on the gel: (its contacts, rest, current).
        _type_read_about: the centres the last fit read its type about; None: its maxima.
    """

    def _fit(
        self,
        rest_px: np.ndarray,
        current: np.ndarray,
        valid: np.ndarray,
        held: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        """:meth:`_contacts_and_gesture` computed afresh: the gel's motion in its mount removed
        (docs/method.md, "Gel motion"), the contacts ("Contacts"; ``held``: the press's
        :attr:`Contacts.held` of the window before) found on the positions undistorted by the
        camera model ("Camera model": one px one base-plane mm / px_per_mm everywhere) and put
        back in the image, the gesture's similarity and a learned type ("Gesture")."""
        c = self.config
        begin = self._clock()
        on_gel, now_on_gel, motion = self._on_gel(rest_px, current, valid)
        contacts = detect_contacts(
            on_gel,
            now_on_gel,
            valid,
            r_px=c.r_px,
            a=c.a,
            n_min=c.n_min,
            max_iters=c.homography_max_iters,
            method=c.homography_method,
            refine_px=c.contact_refine_px,
            plateau_fraction=c.plateau_fraction,
            pitch_px=c.marker_pitch_px,
            spike_fraction=c.spike_fraction,
            bump_span_px=self.sensor.gel_radius_px,
            min_move_px=c.min_move_px,
            neighbours=self._of_rest(
                "undistorted neighbours", on_gel, lambda rest: rest_neighbours(rest, c.marker_pitch_px)
            ),
            long_before=self._long_press,
            held=held,
        )
        if contacts.peaks_px is contacts.points_px:  # back to the image
            points = peaks = self.sensor.distort(contacts.points_px)
        else:  # (one call: the camera model's inverse costs ~30 us a call)
            both = self.sensor.distort(np.concatenate([contacts.points_px, contacts.peaks_px]))
            points, peaks = both[: len(contacts.points_px)], both[len(contacts.points_px) :]
        if motion is not None:  # the contact points where they are, the gel's motion included
            points = motion.apply(points)
            peaks = points if contacts.peaks_px is contacts.points_px else motion.apply(peaks)
        contacts = dataclasses.replace(contacts, points_px=points, peaks_px=peaks)
        self._fitted_on_gel = (contacts, on_gel, now_on_gel)
        self._record("contacts", begin)
        begin = self._clock()
        centres = self._type_centres(contacts)

        def gesture(type_centres_px: np.ndarray | None) -> GestureResult:
            return estimate_gesture(
                rest_px,
                current,
                valid,
                contacts.peaks_px,  # A and the intensity about the largest deformation (paper)
                self.sensor,
                r_px=c.r_px,
                reproj_factor=c.gesture_reproj_factor,
                min_reproj_px=c.min_gesture_reproj_px,
                min_intensity_px=c.min_intensity_px,
                intensity_sigma_px=c.intensity_sigma_px,
                origin_radius_px=c.origin_radius_px,
                gel_motion=motion,
                type_centres_px=type_centres_px,
            )

        result = gesture(centres)
        if centres is not None and result.intensity_mm < PROVISIONAL_MM:  # a weak field places no finger
            centres, result = None, gesture(None)
        self._type_read_about = centres
        result = self._learned_type(result, contacts, rest_px, current, valid)
        if c.intensity_gain != 1.0:  # an adapted model's (docs/method.md, "Adaptation")
            result = dataclasses.replace(result, intensity_mm=result.intensity_mm * c.intensity_gain)
        self._record("gesture", begin)
        return contacts, result

    def _on_gel(self, rest_px: np.ndarray, current: np.ndarray, valid: np.ndarray):
        """The positions the contact step reads: ``(rest, current, motion)``, both (N, 2) float64
        px undistorted by the camera model (docs/method.md, "Camera model"), ``current`` without
        the gel's motion in its mount (``motion``, a ``GelMotion`` or None; "Gel motion")."""
        centre = self.sensor.gel_center_px
        rim = self._of_rest("rim", rest_px, lambda rest: rim_markers(rest, centre))
        motion = estimate_gel_motion(rest_px, current, valid, rim, centre)
        on_gel = self._of_rest("undistorted", rest_px, self.sensor.undistort)
        return on_gel, self.sensor.undistort(current if motion is None else motion.remove(current)), motion

    @staticmethod
    def _type_centres(contacts: Contacts) -> np.ndarray | None:
        """The centres the type is read about (docs/method.md, "Gesture"): the bump fit's fingers
        where they all lie inside their maxima (``contacts_bump.maxima_pushed_out``), else None
        (about the maxima; so too, in :meth:`_fit`, below the episode vote's ``PROVISIONAL_MM``)."""
        if contacts.points_px is contacts.peaks_px or not maxima_pushed_out(contacts.peaks_px, contacts.points_px):
            return None
        return contacts.points_px

    def type_centres_of(self, contacts: Contacts) -> np.ndarray:
        """(K, 2) px: the centres the window just fitted (``contacts``, its :class:`Contacts`) read
        its type about: the fitted fingers or the maxima (:meth:`_type_centres`)."""
        return contacts.peaks_px if self._type_read_about is None else self._type_read_about

    def _learned_type(self, result: GestureResult, contacts: Contacts, rest_px, current, valid) -> GestureResult:
        """A window the rule calls a gesture gets the type of the learned classifier
        (``learned.py``, the settings' parameters; docs/method.md, "Gesture", "Adaptation"), its
        contact motion read about the centres the rule read the type about (:meth:`type_centres_of`)."""
        if result.gesture is GestureType.NONE:
            return result
        c = self.config
        features = gesture_features(
            result, self.type_centres_of(contacts), rest_px, current, valid, self.sensor, c.r_px, c.origin_radius_px
        )
        return dataclasses.replace(result, gesture=learned_gesture(features, c.classifier))

    def _counter_drag(self) -> float:
        """How far (mm) the gel moves against the drag of the lone contact of the window being
        voted on (``counter_drag.counter_drag_mm``), on the positions the contact step read: undistorted
        and without the gel's motion in its mount (docs/method.md, "Contacts", "Gel motion");
        inf when that window is not known or has not one contact."""
        if self._voted is None or len(self._voted[3].indices) != 1:
            return math.inf
        rest_px, current, valid, contacts = self._voted
        fitted = self._fitted_on_gel
        if fitted is not None and fitted[0] is contacts:  # the fit's own (the common case)
            on_gel, now = fitted[1], fitted[2]
        else:  # contacts kept from an earlier fit: the same positions, computed again
            on_gel, now, _ = self._on_gel(rest_px, current, valid)
        return counter_drag_mm(
            on_gel, now, valid, int(contacts.indices[0]), self.config.marker_pitch_px, self.sensor.px_per_mm
        )
