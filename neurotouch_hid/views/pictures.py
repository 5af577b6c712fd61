"""Pictures of what the pipeline sees: the ``view`` command's work.

One picture per APS frame: the frame (grey), the events of the last 10 ms (ON green, OFF red,
as the paper's Figure "APS frame and EVS events"), the tracked markers, their displacement
from rest as arrows (scaled up to be visible, never past the neighbouring marker), the contact
points, the gesture type and intensity, and a key to the colours. Drawing is OpenCV's; so is
writing a png (one picture: the frame with the largest gesture intensity); a gif is Pillow's and
an mp4 imageio's (ffmpeg), the optional extra ``video`` (:mod:`neurotouch_hid.service.extras`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from neurotouch_hid.core.atomic import replacing
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.methods import MethodConfig, pipeline_for
from neurotouch_hid.pipeline.track import pipeline_over
from neurotouch_hid.service.extras import require, require_ffmpeg
from neurotouch_hid.sources import EVENT_DTYPE, Frame

#: Output kinds by file suffix.
VIEW_SUFFIXES = (".mp4", ".gif", ".png")

#: The most pictures a gif takes: Pillow holds each until the file is written (0.4 MiB a picture
#: at scale 2, so 750 pictures, 30 s at 25 frames a second, are ~300 MiB); mp4 has no bound.
MAX_GIF_PICTURES = 750

#: Colours (RGB).
ON_RGB, OFF_RGB = (0, 220, 0), (230, 0, 0)
MARKER_RGB, ARROW_RGB, CONTACT_RGB, TEXT_RGB = (255, 230, 0), (0, 200, 255), (255, 0, 255), (255, 255, 255)


def draw_view(
    image: np.ndarray,
    events: np.ndarray,
    markers_px: np.ndarray,
    rest_px: np.ndarray,
    estimate: GestureEstimate | None,
    *,
    scale: int = 2,
    arrow_gain: float = 3.0,
) -> np.ndarray:
    """Draw one picture.

    Args:
        image: uint8 (H, W) APS frame, image frame.
        events: EVENT_DTYPE array, the events to show (e.g. the last 10 ms).
        markers_px: (N, 2) float, tracked positions (px), NaN rows for lost markers.
        rest_px: (N, 2) float, rest positions (px).
        estimate: the latest window's estimate, or None.
        scale: integer upscaling of the picture (so text and arrows are readable).
        arrow_gain: displacement arrows are drawn this many times longer than the displacement.
    Returns:
        uint8 (H*scale, W*scale, 3) RGB picture.
    """
    h, w = image.shape
    rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    if len(events):
        x, y = events["x"].astype(np.intp), events["y"].astype(np.intp)
        inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        on = events["polarity"] == 1
        rgb[y[inside & ~on], x[inside & ~on]] = OFF_RGB
        rgb[y[inside & on], x[inside & on]] = ON_RGB
    pic = cv2.resize(rgb, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    k = scale * (1 << shift)

    def at(p: np.ndarray) -> tuple[int, int]:
        return int(round((p[0] + 0.5) * k - k / (2 * scale))), int(round((p[1] + 0.5) * k - k / (2 * scale)))

    gain = arrow_scale(markers_px, rest_px, arrow_gain)
    for cur, rest in zip(markers_px, rest_px):
        if not np.all(np.isfinite(cur)):
            continue
        tip = rest + gain * (cur - rest)
        if np.hypot(*(cur - rest)) >= 0.3:
            cv2.arrowedLine(pic, at(rest), at(tip), ARROW_RGB, 2, cv2.LINE_AA, shift, tipLength=0.3)
        cv2.circle(pic, at(cur), 3 * (1 << shift), MARKER_RGB, 1, cv2.LINE_AA, shift)  # hollow: events show
    lines = ["no estimate yet"]
    if estimate is not None:
        for c in estimate.contacts_px:
            cv2.circle(pic, at(c), 9 * (1 << shift), CONTACT_RGB, 2, cv2.LINE_AA, shift)
        lines = [
            f"{estimate.gesture.value}  {estimate.intensity_mm:.1f} mm",
            f"{'resting' if estimate.resting else 'moving'}  t={estimate.t_us / 1e6:.2f} s",
        ]
    for i, text in enumerate(lines):
        _label(pic, text, (8, 22 + 22 * i), 0.6)
    _colour_key(pic, gain)
    return pic


def _label(pic: np.ndarray, text: str, org: tuple[int, int], size: float, colour=TEXT_RGB) -> None:
    """White (or ``colour``) text with a black outline, readable on any frame."""
    cv2.putText(pic, text, org, cv2.FONT_HERSHEY_SIMPLEX, size, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(pic, text, org, cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)


def colour_key(gain: float) -> list[tuple[str, tuple[int, int, int]]]:
    """What each colour of a picture means: (label, RGB), as drawn in its bottom-left corner."""
    return [
        ("ON events", ON_RGB),
        ("OFF events", OFF_RGB),
        ("markers", MARKER_RGB),
        (f"displacement x{gain:.1f}", ARROW_RGB),
        ("contacts", CONTACT_RGB),
    ]


def _colour_key(pic: np.ndarray, gain: float) -> None:
    key = colour_key(gain)
    h = pic.shape[0]
    for i, (text, colour) in enumerate(key):
        y = h - 10 - 18 * (len(key) - 1 - i)
        cv2.rectangle(pic, (8, y - 10), (20, y), colour, -1)
        _label(pic, text, (26, y), 0.45, colour)


def arrow_scale(markers_px: np.ndarray, rest_px: np.ndarray, arrow_gain: float) -> float:
    """How many times longer than the displacement the arrows are drawn: ``arrow_gain``, less
    when the largest displacement would then reach past 0.8 of the marker pitch (the median
    distance between neighbouring rest markers, px), where arrows would cross their
    neighbours'."""
    rest = np.asarray(rest_px, dtype=np.float64).reshape(-1, 2)
    moved = np.asarray(markers_px, dtype=np.float64).reshape(-1, 2) - rest
    largest = np.nanmax(np.hypot(moved[:, 0], moved[:, 1]), initial=0.0)
    if len(rest) < 2 or not np.isfinite(largest) or largest <= 0:
        return arrow_gain
    gaps = np.hypot(*(rest[:, None, :] - rest[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    pitch = float(np.median(gaps.min(axis=1)))
    return float(min(arrow_gain, 0.8 * pitch / largest))


def render_view(
    recording: str | Path,
    out: str | Path,
    sensor: SensorGeometry,
    config: MethodConfig | None = None,
    *,
    scale: int = 2,
    fps: float = 25.0,
    event_span_us: int = 10_000,
    on_progress: Callable[[int, int], None] | None = None,
) -> int:
    """Run the pipeline over ``recording`` and write pictures of it to ``out``.

    Args:
        recording: AEDAT4 file (events + APS frames).
        out: ``.mp4`` or ``.gif`` (one picture per APS frame, at ``fps``) or ``.png`` (the
            picture with the largest gesture intensity, else the last).
        sensor: the geometry.
        config: the method's settings (``pipeline.methods``); None = the product's defaults.
        scale: integer upscaling; pictures are (height*scale, width*scale).
        fps: frame rate of mp4/gif.
        event_span_us: how much recent event history each picture shows (us).
        on_progress: see :func:`neurotouch_hid.pipeline.track.pipeline_over`.
    Returns:
        the number of pictures drawn.
    Raises:
        NeurotouchError: ``out`` has another suffix or cannot be written; OutputError: it is a
            symbolic link, a folder or the recording. What was at ``out`` is kept until the
            view is complete.
        MissingExtraError: gif or mp4 without the extra ``video`` (mp4: or without an ffmpeg program).
        RecordingError, SensorError: see :func:`neurotouch_hid.pipeline.track.pipeline_over`.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in VIEW_SUFFIXES:
        raise NeurotouchError(
            f"{out}: the view is written as {', '.join(VIEW_SUFFIXES)}, not {out.suffix or 'no suffix'!r}"
        )
    if suffix == ".mp4":
        require_ffmpeg("view --out FILE.mp4")
    elif suffix == ".gif":
        require("video", "view --out FILE.gif", ("PIL",))
    pipeline = pipeline_for(sensor, config)
    latest: GestureEstimate | None = None

    def pictures() -> Iterator[np.ndarray]:
        """One picture per APS frame once the rest is known, each drawn when asked for."""
        nonlocal latest
        recent: deque[np.ndarray] = deque()
        for item, estimates in pipeline_over(recording, pipeline, on_progress=on_progress):
            if estimates:
                latest = estimates[-1]
            if not isinstance(item, Frame):
                recent.append(item)
                while recent and recent[0]["timestamp"][-1] < item["timestamp"][-1] - event_span_us:
                    recent.popleft()
                continue
            if pipeline.rest_px is None:
                continue
            events = np.concatenate(list(recent)) if recent else np.zeros(0, dtype=EVENT_DTYPE)
            events = events[events["timestamp"] >= item.t_us - event_span_us]
            yield draw_view(item.image, events, pipeline.marker_positions(), pipeline.rest_px, latest, scale=scale)

    drawn = 0

    def counted(limit: int | None = None) -> Iterator[np.ndarray]:
        nonlocal drawn
        for pic in pictures():
            drawn += 1
            if limit is not None and drawn > limit:
                raise NeurotouchError(
                    f"{out}: a gif holds every picture in memory until it is written, and this recording has "
                    f"more than {limit} ({limit / fps:g} s at {fps:g} pictures a second); "
                    "write a .mp4, which is written picture by picture, or cut the recording"
                )
            yield pic

    with replacing(out, (recording,), "view") as target:  # renamed into place when complete
        try:
            if suffix == ".mp4":
                import imageio.v2 as imageio

                writer = imageio.get_writer(target, fps=fps, macro_block_size=1)
                try:
                    for pic in counted():
                        writer.append_data(pic)
                finally:
                    writer.close()
            elif suffix == ".gif":
                _write_gif(target, counted(MAX_GIF_PICTURES), fps)
            else:
                best: tuple[float, np.ndarray] | None = None
                for pic in counted():
                    intensity = latest.intensity_mm if latest is not None else 0.0
                    if best is None or intensity > best[0] or intensity == best[0] == 0.0:
                        best = (intensity, pic)
                if best is not None and not cv2.imwrite(str(target), cv2.cvtColor(best[1], cv2.COLOR_RGB2BGR)):
                    raise NeurotouchError(f"{out}: cannot write the view (OpenCV's imwrite failed)")
        except OSError as exc:
            raise NeurotouchError(f"{out}: cannot write the view: {exc}") from None
    return drawn


def _write_gif(target: Path, pictures: Iterator[np.ndarray], fps: float) -> None:
    """Write ``pictures`` (uint8 (H, W, 3) RGB) as an endlessly looping gif, through Pillow.

    Pillow asks for each picture when it comes to it (``append_images`` is iterated once) and keeps
    each one, reduced to an adaptive 256-colour palette (one byte a pixel), until the file is
    written: the caller bounds their number (:data:`MAX_GIF_PICTURES`).
    """
    from PIL import Image

    first = next(pictures, None)
    if first is None:
        return
    Image.fromarray(first).save(
        target,
        format="GIF",
        save_all=True,
        append_images=(Image.fromarray(pic) for pic in pictures),
        duration=1000.0 / fps,
        loop=0,
    )
