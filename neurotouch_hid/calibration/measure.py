"""Sensor calibration: a ``sensor.yaml`` (docs/dataset.md) measured from APS frames of the gel at rest.

The gel (paper, section "System Overview") is a black dome with white 1 mm dots on a 4 mm grid,
seen from inside by the DAVIS-346. Nothing about the image scale is known in advance, so every
step here is scale-free:

1. **Rest frames** -- the first few APS frames of the source. The marker grid is found on the
   first one (or the source is refused: no gel in view); the markers of every other frame must
   lie within :data:`STILL_MM` of it (or the source is refused: keep your hands off the gel).
   The frames are then averaged, which lowers the noise of what follows.
2. **Markers** -- small bright blobs: a white top-hat (``cv2.MORPH_TOPHAT``) removes the gel's
   background and anything wider than a marker, then :func:`~neurotouch_hid.pipeline.markers.detect_markers`
   thresholds (Otsu), labels (``cv2.connectedComponentsWithStats``) and takes sub-pixel
   centroids. The median nearest-neighbour distance gives a first scale, with which
   :func:`~neurotouch_hid.pipeline.markers.looks_like_marker_grid` checks for 1 mm dots 4 mm
   apart; a lattice test (each marker has neighbours in directions repeating every 90 degrees,
   or 60 for a hexagonal grid) tells the grid from bright spots that happen to be as regular.
3. **Gel circle** -- the gel's disc is brighter than its surroundings (in the simulator, ~20
   grey levels against ~6). With the markers removed (median filter), Otsu's threshold
   separates the disc; its outline, without the points on the image border, is fitted with
   ``cv2.fitEllipse``. The fit is kept only if it is round, has contrast, holds the marker grid
   and is centred on it; otherwise the circle is the marker grid's extent plus one marker
   spacing (4 mm), and the result says so.
4. **Scale** -- px_per_mm is the scale *at the gel's centre*: the dome foreshortens the grid
   towards the rim (in the simulator the median spacing over the whole grid is ~15 % short),
   so it is the median length of the :data:`CENTRE_PAIRS` neighbouring-marker pairs nearest the
   centre (the edges of the central 3x3 block of the grid), divided by 4 mm.
   **Camera model** -- then the radial camera model of :mod:`neurotouch_hid.core.camera_model` is
   fitted to the grid (each marker's index on the 4 mm grid laid on the dome, against its image
   radius): sensor.yaml gets its px_per_mm at the centre and ``radial_k``, which map image px to
   gel mm over the whole gel (not in the paper; a note says so when the markers do not index
   as the grid, and the linear scale stays).
5. **Rest layout** -- the markers of the averaged rest frame are written to sensor.yaml as
   ``rest_markers_px`` (image px): the pipeline refuses a first frame whose markers are off this
   layout (a run that starts with the gel pressed; docs/method.md, "Markers").
6. **Marker count** -- refused below half the expected count (paper: 177), noted when off by
   more than :data:`COUNT_TOLERANCE`.
7. **Creep** (``calibrate --press``, optional) -- a soft gel creeps under a held finger and
   relaxes slowly after it: :func:`measure_creep` tracks a recorded press with the pipeline and
   fits a standard linear solid to its amplitude (:mod:`neurotouch_hid.pipeline.creep`);
   sensor.yaml gets ``creep`` (q, tau), with which the pipeline tells a release's relaxation
   from a gesture (docs/method.md, "Creep"), or none when the press relaxes as an elastic gel's.

Mirror and rotation cannot be seen on a rest frame: :func:`calibrate` leaves SensorGeometry's
defaults (mirror, as the camera looks from inside; no rotation); ``calibrate`` measures them
from two guided pushes and then checks every gesture (:mod:`neurotouch_hid.calibration.guide`).
"""

from __future__ import annotations

import contextlib
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np
import yaml

from neurotouch_hid.core.camera_model import fit_camera_model
from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.creep import AMPLITUDE_MARKERS
from neurotouch_hid.pipeline.markers import (
    MARKER_SPACING_MM,
    Markers,
    detect_markers,
    looks_like_marker_grid,
    nearest_neighbour_distances,
)
from neurotouch_hid.sources import Frame

#: Markers on the paper's gel (section "System Overview"): the default expected count.
EXPECTED_MARKERS = 177
#: A press's amplitude is the mean displacement of this many markers, the most displaced (the
#: creep filter reads the same: ``creep.amplitude``).
PRESS_MARKERS = AMPLITUDE_MARKERS
#: Rest frames averaged by default (0.4 s at the DAVIS-346's 25 Hz), and the fewest accepted.
REST_FRAMES = 10
MIN_REST_FRAMES = 3
#: How long to wait for the live camera's rest frames (s of the camera's clock).
CAMERA_WAIT_S = 10.0
#: Largest marker image looked for (px): a 1 mm dot at 10 px/mm, where the 60 mm gel would be
#: 600 px wide, more than the whole image. The top-hat's kernel is twice as wide (it keeps the dots
#: and removes anything wider), blobs up to twice such a dot's area are kept.
MAX_MARKER_PX = 10
#: A blob farther than this times the median nearest-neighbour distance from every other blob
#: is not part of the grid (a reflection, a hot pixel).
ISOLATED_RATIO = 1.5
#: A marker moved during calibration when it moved more than this on the gel (mm; the
#: simulator's rest-frame centroids jitter by ~0.03 mm), and the gel moved when more than
#: STILL_FRACTION of the markers (and at least 2) did.
STILL_MM = 0.2
STILL_FRACTION = 0.02
#: Neighbouring-marker pairs nearest the centre whose median length is the centre's spacing.
CENTRE_PAIRS = 12
#: Two markers are neighbours when closer than this times either one's nearest-neighbour
#: distance (a square grid's diagonal neighbours are sqrt(2) = 1.41x farther).
NEIGHBOUR_RATIO = 1.25
#: A grid's markers have on average at least GRID_NEIGHBOURS neighbours (a square grid's inner
#: markers 4, a hexagonal one's 6; the simulated gel's 177 markers 3.7), and the directions to
#: them repeat every 90 (or 60) degrees: the order |mean(exp(4i theta))| (or 6i) is at least
#: GRID_ORDER (the simulated gel: 0.99). Bright spots of a street scene: ~1 neighbour, order < 0.4.
GRID_NEIGHBOURS = 2.5
GRID_ORDER = 0.6
#: The gel's edge is accepted when the fitted ellipse's axes differ by less than 10 %, the disc
#: is at least EDGE_CONTRAST grey levels brighter than its surroundings, it holds EDGE_INSIDE of
#: the markers, and its centre is within one marker spacing of the grid's centre.
EDGE_ROUNDNESS = 0.9
EDGE_CONTRAST = 3.0
EDGE_INSIDE = 0.98
#: Marker count: refused below MIN_COUNT_FRACTION of the expected count, noted beyond COUNT_TOLERANCE.
MIN_COUNT_FRACTION = 0.5
COUNT_TOLERANCE = 0.1

_CHECK = (
    "check that the camera looks at the NeuroTouch gel from inside, that the gel is lit "
    "(LED ring on) and that the APS frames are neither black nor saturated"
)


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate` measured.

    Attributes:
        sensor: the geometry (docs/dataset.md): image size, px_per_mm at the gel's centre, gel circle
            (image frame, px); mirror and rotation_deg are SensorGeometry's defaults.
        markers_px: (N, 2) float64 marker centroids on the averaged rest frame, image frame, px.
        spacing_px: median distance between neighbouring markers near the centre (px; 4 mm).
        grid_center_px: (x, y) mean of the markers (px), the grid's centre.
        edge_found: True when the gel circle was fitted to the gel's visible edge, False when
            it is the marker grid's extent plus one spacing.
        frames_t_us: timestamps (us) of the rest frames averaged.
        notes: one line each for the user: what was assumed or looks off (marker count, no edge).
    """

    sensor: SensorGeometry
    markers_px: np.ndarray
    spacing_px: float
    grid_center_px: tuple[float, float]
    edge_found: bool
    frames_t_us: tuple[int, ...]
    notes: tuple[str, ...]

    @property
    def n_markers(self) -> int:
        """Markers found inside the gel circle."""
        return int(len(self.markers_px))


def calibrate(
    frames: Iterable[Frame], *, expected_markers: int = EXPECTED_MARKERS, n_frames: int = REST_FRAMES
) -> Calibration:
    """Measure the sensor geometry from APS frames of the gel at rest (module docstring).

    Args:
        frames: APS frames, uint8 (height, width) grey (260x346 for a DAVIS-346); only the first
            ``n_frames`` are read.
        expected_markers: the gel's marker count (paper: 177).
        n_frames: rest frames to read, at least :data:`MIN_REST_FRAMES`.
    Returns:
        :class:`Calibration`.
    Raises:
        SensorError (one line saying what to check): fewer than MIN_REST_FRAMES frames, frames
            that are not 2-D uint8 or change size; no marker grid in view (another scene, dark or
            empty frames); the gel moved between the frames; fewer than half the expected markers.
        ValueError: ``n_frames`` < MIN_REST_FRAMES or ``expected_markers`` < 1.
    """
    if n_frames < MIN_REST_FRAMES:
        raise ValueError(f"n_frames must be >= {MIN_REST_FRAMES}, got {n_frames}")
    if expected_markers < 1:
        raise ValueError(f"expected_markers must be >= 1, got {expected_markers}")
    rest = list(itertools.islice(frames, n_frames))
    if len(rest) < MIN_REST_FRAMES:
        raise SensorError(
            f"calibration needs at least {MIN_REST_FRAMES} APS frames of the gel at rest, the source gave {len(rest)}"
        )
    shapes = {np.shape(f.image) for f in rest}
    if len(shapes) > 1:
        raise SensorError(f"the APS frames change size during calibration ({sorted(shapes)})")

    first = _grid(rest[0].image)
    _check_still(first, rest)
    mean = np.rint(np.mean([f.image for f in rest], axis=0)).astype(np.uint8)
    markers = _grid(mean)
    points = markers.centroids_px.astype(np.float64)
    grid_center = points.mean(axis=0)
    nn = nearest_neighbour_distances(points)
    rough_spacing = float(np.median(nn))

    notes: list[str] = []
    edge = _gel_edge(mean, points, grid_center, rough_spacing)
    if isinstance(edge, str):
        notes.append(
            f"the gel's edge is not visible ({edge}): the gel circle is the marker grid's extent "
            f"plus one marker spacing ({MARKER_SPACING_MM:g} mm)"
        )
    center = grid_center if isinstance(edge, str) else edge[0]
    spacing = _centre_spacing(points, nn, center)
    if isinstance(edge, str):
        radius = float(np.hypot(*(points - center).T).max()) + spacing
    else:
        radius = edge[1]
        points = points[np.hypot(*(points - center).T) <= radius]

    n = len(points)
    if n < MIN_COUNT_FRACTION * expected_markers:
        raise SensorError(
            f"only {n} markers found on the gel, fewer than half the {expected_markers} expected "
            f"(--markers): {_CHECK}, and that the whole gel is in view"
        )
    if abs(n - expected_markers) > COUNT_TOLERANCE * expected_markers:
        notes.append(
            f"{n} markers found, {expected_markers} expected (--markers): off by more than "
            f"{COUNT_TOLERANCE:.0%}; check that the whole gel is in view and lit evenly"
        )
    height, width = mean.shape
    sensor = SensorGeometry(
        width=width,
        height=height,
        px_per_mm=round(spacing / MARKER_SPACING_MM, 4),
        gel_center_px=(round(float(center[0]), 2), round(float(center[1]), 2)),
        gel_radius_px=round(radius, 2),
        extra={"rest_markers_px": [[round(float(x), 2), round(float(y), 2)] for x, y in points]},
    )
    fitted = fit_camera_model(points, sensor)
    if fitted is None:
        notes.append(
            f"the markers do not index as a {MARKER_SPACING_MM:g} mm grid on the dome: no camera model "
            "(radial_k), one px_per_mm over the whole gel"
        )
    else:
        sensor = fitted
    return Calibration(
        sensor,
        points,
        spacing,
        (float(grid_center[0]), float(grid_center[1])),
        not isinstance(edge, str),
        tuple(f.t_us for f in rest),
        tuple(notes),
    )


def _blobs(image: np.ndarray) -> Markers:
    """Small bright blobs of a uint8 (H, W) image (px), whatever the scale: white top-hat, then
    :func:`detect_markers` over the whole image (Otsu threshold, sub-pixel centroids)."""
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise SensorError(f"APS frame must be a 2-D uint8 grey image, got shape {img.shape} dtype {img.dtype}")
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * MAX_MARKER_PX + 1,) * 2)
    tophat = cv2.morphologyEx(img, cv2.MORPH_TOPHAT, kernel)
    height, width = img.shape
    whole = SensorGeometry(
        width=width,
        height=height,
        gel_center_px=(width / 2, height / 2),
        gel_radius_px=float(math.hypot(width, height)),
    )
    return detect_markers(tophat, whole, min_area_px=2, max_area_px=2 * math.pi * (MAX_MARKER_PX / 2) ** 2)


def _grid(image: np.ndarray) -> Markers:
    """The marker grid of a frame, the blobs far from every other blob left out.

    Raises SensorError (no gel in view) when the blobs are not a grid of 1 mm dots 4 mm apart
    (:func:`looks_like_marker_grid` at the scale their median spacing implies).
    """
    blobs = _blobs(image)
    if len(blobs) >= 2:
        nn = nearest_neighbour_distances(blobs.centroids_px)
        keep = nn <= ISOLATED_RATIO * np.median(nn)
        blobs = Markers(blobs.centroids_px[keep], blobs.sizes_px[keep])
    if len(blobs) >= 3:
        points = blobs.centroids_px.astype(np.float64)
        nn = nearest_neighbour_distances(points)
        low, high = points.min(axis=0), points.max(axis=0)
        # a grid spreads in 2-D: its bounding box must be at least a quarter as high as wide and
        # vice versa (looks_like_marker_grid wants it gel_radius_px wide and high)
        rough = SensorGeometry(
            width=image.shape[1],
            height=image.shape[0],
            px_per_mm=float(np.median(nn)) / MARKER_SPACING_MM,
            gel_center_px=tuple((low + high) / 2),
            gel_radius_px=float((high - low).max() / 4),
        )
        i, j = _neighbour_pairs(points, nn)
        angles = np.arctan2(*(points[j] - points[i]).T[::-1])
        order = max(abs(np.mean(np.exp(4j * angles))), abs(np.mean(np.exp(6j * angles)))) if len(i) else 0.0
        if looks_like_marker_grid(blobs, rough) and 2 * len(i) >= GRID_NEIGHBOURS * len(points) and order >= GRID_ORDER:
            return blobs
    raise SensorError(
        f"no gel in view: the APS frames show no grid of markers {MARKER_SPACING_MM:g} mm apart "
        f"({len(blobs)} small bright spots, brightest grey level {int(np.max(image))}); {_CHECK}"
    )


def _check_still(reference: Markers, frames: list[Frame]) -> None:
    """Raise SensorError when, in any frame, more than STILL_FRACTION of the markers of
    ``reference`` (the first frame's grid) moved more than STILL_MM. A marker with no blob within
    half a spacing in a frame is not counted (dim markers flicker when the dots are ~1.5 px)."""
    ref = reference.centroids_px.astype(np.float64)
    spacing = float(np.median(nearest_neighbour_distances(ref)))
    tolerance = STILL_MM / MARKER_SPACING_MM * spacing
    allowed = max(2, int(STILL_FRACTION * len(ref)))
    for k, frame in enumerate(frames[1:], start=1):
        found = _blobs(frame.image).centroids_px.astype(np.float64)
        if len(found) == 0:
            continue
        shift = np.hypot(ref[:, None, 0] - found[None, :, 0], ref[:, None, 1] - found[None, :, 1]).min(axis=1)
        moved = int(np.sum((shift > tolerance) & (shift < spacing / 2)))
        if moved > allowed:
            raise SensorError(
                f"the gel moved during calibration ({moved} of {len(ref)} markers moved more than "
                f"{STILL_MM:g} mm between rest frames 1 and {k + 1}): keep your hands off the gel "
                f"and calibrate again"
            )


def _gel_edge(
    image: np.ndarray, points: np.ndarray, grid_center: np.ndarray, spacing: float
) -> tuple[np.ndarray, float] | str:
    """The gel circle fitted to the disc's visible edge: ((cx, cy) px, radius px), or the reason
    it was not accepted (str). ``points`` (N, 2) are the markers (px), ``spacing`` their median
    nearest-neighbour distance (px)."""
    size = int(spacing) | 1  # odd median window, ~ one grid cell: the markers vanish in it
    background = cv2.medianBlur(image, max(3, size))
    _, disc = cv2.threshold(background, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(disc, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    centre_px = (float(grid_center[0]), float(grid_center[1]))
    around = [c for c in contours if cv2.pointPolygonTest(c, centre_px, False) > 0]
    if not around:
        return "no bright disc around the marker grid"
    outline = max(around, key=cv2.contourArea)[:, 0, :]
    height, width = image.shape
    inner = (outline[:, 0] > 0) & (outline[:, 1] > 0) & (outline[:, 0] < width - 1) & (outline[:, 1] < height - 1)
    if inner.sum() < 5:
        return "the disc's outline lies on the image border"
    (cx, cy), axes, _ = cv2.fitEllipse(outline[inner].astype(np.float32))
    if min(axes) < EDGE_ROUNDNESS * max(axes):
        return f"the bright region around the grid is not round (axes {min(axes):.0f} and {max(axes):.0f} px)"
    # The outline runs through the centres of the disc's outermost pixels, half a pixel inside its edge.
    center, radius = np.array([cx, cy]), float(sum(axes)) / 4.0 + 0.5
    r = np.hypot(*np.mgrid[0:height, 0:width][::-1] - center[:, None, None])
    inside = float(np.median(background[(r > radius - spacing) & (r < radius - 1)]))
    outside = float(np.median(background[(r > radius + 1) & (r < radius + spacing)]))
    if inside - outside < EDGE_CONTRAST:
        return f"the disc is only {inside - outside:.1f} grey levels brighter than its surroundings"
    if np.mean(np.hypot(*(points - center).T) <= radius) < EDGE_INSIDE:
        return "markers lie outside the bright disc"
    offset = float(np.hypot(*(center - grid_center)))
    if offset > spacing:
        return f"the bright disc's centre is {offset:.1f} px from the marker grid's"
    return center, radius


def _neighbour_pairs(points: np.ndarray, nn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j), i < j, of the neighbouring pairs among (N, 2) ``points`` (px) whose
    nearest-neighbour distances are ``nn`` (N,): closer than NEIGHBOUR_RATIO times either's."""
    d = np.hypot(points[:, None, 0] - points[None, :, 0], points[:, None, 1] - points[None, :, 1])
    return np.nonzero(np.triu(d < NEIGHBOUR_RATIO * np.minimum(nn[:, None], nn[None, :]), k=1))


def _centre_spacing(points: np.ndarray, nn: np.ndarray, center: np.ndarray) -> float:
    """Median length (px) of the CENTRE_PAIRS neighbouring-marker pairs whose midpoints are
    nearest ``center``: (N, 2) ``points`` px, ``nn`` (N,) their nearest-neighbour distances."""
    i, j = _neighbour_pairs(points, nn)
    middle = np.hypot(*((points[i] + points[j]) / 2 - center).T)
    nearest = np.argsort(middle)[:CENTRE_PAIRS]
    return float(np.median(np.hypot(*(points[i[nearest]] - points[j[nearest]]).T)))


def read_rest_frames(source: str | Path, n_frames: int = REST_FRAMES) -> list[Frame]:
    """The first ``n_frames`` APS frames of the AEDAT4 recording ``source`` (the live camera's
    and the simulator's: :mod:`neurotouch_hid.calibration.guide`, which keeps them open for the
    guided pushes).

    Returns:
        up to ``n_frames`` :class:`Frame` values (uint8 (260, 346) for a DAVIS-346), in time order.
    Raises:
        RecordingError: the recording cannot be read or has no APS frames.
    """
    from neurotouch_hid.sources.recording import RecordingReader

    with RecordingReader(source, require_frames=True) as reader, contextlib.closing(reader.stream()) as stream:
        return list(itertools.islice((item for item in stream if isinstance(item, Frame)), n_frames))


def sensor_changes(old: SensorGeometry, new: SensorGeometry) -> list[str]:
    """The docs/dataset.md fields that differ, one ``"field: old -> new"`` string each (YAML values)."""

    def text(value) -> str:
        return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()

    before, after = old.to_dict(), new.to_dict()
    return [
        f"{key}: {text(before.get(key))} -> {text(value)}" for key, value in after.items() if before.get(key) != value
    ]


def press_amplitude(recording: str | Path, sensor: SensorGeometry) -> tuple[np.ndarray, np.ndarray]:
    """The deformation's amplitude over a recording: at each window's end (the pipeline's
    defaults, 10 ms), the mean of the :data:`PRESS_MARKERS` largest tracked marker displacements
    from rest (px, image frame; lost markers left out).

    Returns:
        (t_us (T,) int64 us, amplitude (T,) float64 px).
    Raises:
        RecordingError: the file cannot be read (see ``track.pipeline_over``).
        SensorError: no gel on its first APS frame.
    """
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.pipeline.track import pipeline_over

    times: list[int] = []
    amplitude: list[float] = []

    def keep(estimate) -> None:
        moved = np.hypot(*(pipeline.marker_positions() - pipeline.rest_px).T)
        moved = moved[np.isfinite(moved)]
        times.append(estimate.t_us)
        amplitude.append(float(np.sort(moved)[-PRESS_MARKERS:].mean()) if len(moved) else 0.0)

    pipeline = GesturePipeline(sensor, on_window=keep)
    for _ in pipeline_over(recording, pipeline):
        pass
    return np.array(times, dtype=np.int64), np.array(amplitude)


def measure_creep(recording: str | Path, sensor: SensorGeometry) -> tuple[float, float] | None:
    """The gel's creep (q, tau s), sensor.yaml's ``creep``, from a recording of a press: one
    finger pressed into the gel, held still ~2 s, lifted quickly, then the gel left alone ~2 s
    (:func:`neurotouch_hid.pipeline.creep.fit_creep` on :func:`press_amplitude`); None when the
    gel does not creep (an elastic gel explains the press nearly as well).

    Raises:
        SensorError: the recording shows no press held and released (what to do is said);
            RecordingError / SensorError of :func:`press_amplitude`.
    """
    from neurotouch_hid.pipeline.creep import fit_creep

    t_us, amplitude = press_amplitude(recording, sensor)
    try:
        return fit_creep(t_us, amplitude)
    except ValueError as exc:
        raise SensorError(f"{recording}: cannot measure the gel's creep: {exc}") from None
