"""The simulated camera: marker rendering, APS frames and ESIM events (numba).

The gel is a black surface with white markers (paper, section "System Overview"), so the image is
a constant background plus one small bright blob per marker. Only the markers are rendered: each
marker is splatted into a 9x9 px patch as a pixel-integrated Gaussian (separable: the integral of
a Gaussian over a pixel is a product of two differences of the normal CDF), which places its
centroid with sub-pixel accuracy.

Events follow ESIM (Rebecq, Gehrig, Scaramuzza, "ESIM: an Open Event Camera Simulator", CoRL
2018): between two renders the log intensity of each pixel is assumed to change linearly; every
crossing of the pixel's reference level +- its contrast threshold makes one event whose timestamp
is interpolated linearly between the renders. Renders are adaptive: the caller gives marker
positions on a 1 ms grid and :func:`esim_chunk` subdivides each millisecond so that no marker
moves more than ``max_step_px`` between renders. Only markers that moved re-render, and only the
pixels of their patches are compared with their reference, so a gel at rest costs almost nothing.
Sensor non-idealities: per-pixel threshold mismatch (ON and OFF thresholds drawn per pixel),
a refractory period, background-activity noise and hot pixels (:func:`noise_events`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE

#: Half-size of a marker's patch (px): patches are (2 * PATCH_RADIUS + 1)^2 pixels.
PATCH_RADIUS = 4
#: Added to grey levels before the log (ESIM's log(I + eps)), grey levels.
LOG_EPS = 1.0
#: Background-activity rate per pixel (Hz) of the simulated camera by default: the low end of a
#: DAVIS-346 in good light (the rate grows as the light dims, to a few Hz per pixel).
NOISE_RATE_HZ = 0.1
#: Mean contrast threshold C of the simulated DAVIS's event pixels (log units), ON and OFF alike.
CONTRAST = 0.25
#: Pixel-to-pixel spread (sigma, log units) of the contrast thresholds (threshold mismatch).
CONTRAST_SIGMA = 0.03
#: A pixel whose intensity changed by less than this fraction since its last log evaluation is
#: not evaluated (the change is kept and counted once it adds up): 1 % is ~ C / 25.
SKIP_REL = 0.01


@numba.njit(cache=True, nogil=True)
def _phi(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z * 0.7071067811865476))


@numba.njit(cache=True, nogil=True)
def _pixel_weights(center: float, sigma: float, first: int, out: np.ndarray) -> None:
    """Integral over pixels first..first+len(out)-1 of a unit-peak-normalised Gaussian (1-D)."""
    norm = 1.0 / (_phi(0.5 / sigma) - _phi(-0.5 / sigma))
    lo = _phi((first - 0.5 - center) / sigma)
    for k in range(out.shape[0]):
        hi = _phi((first + k + 0.5 - center) / sigma)
        out[k] = (hi - lo) * norm
        lo = hi


@numba.njit(cache=True, nogil=True)
def splat(
    img: np.ndarray,
    x: float,
    y: float,
    amp: float,
    sigma: float,
    dirty: np.ndarray,
    dirty_list: np.ndarray,
    n_dirty: int,
    gx: np.ndarray,
    gy: np.ndarray,
) -> int:
    """Add one marker (pixel-integrated Gaussian, peak ``amp`` grey levels when centred on a
    pixel, ``sigma`` px) to ``img`` (H, W) float32 at image position (x, y) px. Pixels touched
    are appended once to ``dirty_list`` (flat indices) when ``dirty`` is given (size > 0).
    ``gx``, ``gy``: scratch arrays of 2 * PATCH_RADIUS + 1 float64. Returns the new number of
    dirty pixels."""
    h, w = img.shape
    cx = int(math.floor(x + 0.5))
    cy = int(math.floor(y + 0.5))
    size = 2 * PATCH_RADIUS + 1
    _pixel_weights(x, sigma, cx - PATCH_RADIUS, gx)
    _pixel_weights(y, sigma, cy - PATCH_RADIUS, gy)
    track = dirty.shape[0] > 0
    for j in range(size):
        yy = cy - PATCH_RADIUS + j
        if yy < 0 or yy >= h:
            continue
        for i in range(size):
            xx = cx - PATCH_RADIUS + i
            if xx < 0 or xx >= w:
                continue
            img[yy, xx] += amp * gx[i] * gy[j]
            if track:
                flat = yy * w + xx
                if dirty[flat] == 0:
                    dirty[flat] = 1
                    dirty_list[n_dirty] = flat
                    n_dirty += 1
    return n_dirty


@numba.njit(cache=True, nogil=True)
def render_exposure(background: np.ndarray, pos: np.ndarray, amp: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """The light an APS frame's pixels gather: the average of renders over the exposure.

    Args:
        background: (H, W) float64 grey levels without markers.
        pos: (S, N, 2) float64 marker positions (image px) at S instants of the exposure.
        amp: (S, N) float64 marker peak brightness above the background (grey levels).
        sigma: (S, N) float64 marker blob sigma (px) at those instants.
    Returns:
        (H, W) float64 grey levels, before the read-out's noise (:func:`read_out`).
    """
    img = background.copy()
    no_dirty = np.zeros(0, dtype=np.uint8)
    no_list = np.zeros(0, dtype=np.int32)
    gx = np.empty(2 * PATCH_RADIUS + 1)
    gy = np.empty(2 * PATCH_RADIUS + 1)
    s_count = pos.shape[0]
    none_dirty = np.int64(0)  # typed as esim_chunk's count: splat compiles once
    for s in range(s_count):
        for n in range(pos.shape[1]):
            splat(
                img, pos[s, n, 0], pos[s, n, 1], amp[s, n] / s_count, sigma[s, n], no_dirty, no_list, none_dirty, gx, gy
            )
    return img


@numba.njit(cache=True, nogil=True)
def noise_sigma(img: np.ndarray, read_noise: float, shot_noise: float) -> np.ndarray:
    """(H, W) float64 sigma of each pixel's read-out noise (grey levels): read noise
    ``read_noise`` and shot noise ``shot_noise`` at grey level 1, growing with the square root of
    the grey level of ``img`` (H, W) float64 (:func:`render_exposure`)."""
    out = np.empty(img.shape)
    h, w = img.shape
    for y in range(h):
        for x in range(w):
            out[y, x] = math.sqrt(read_noise * read_noise + shot_noise * shot_noise * max(img[y, x], 0.0))
    return out


@numba.njit(cache=True, nogil=True)
def read_out(img: np.ndarray, sigma: np.ndarray, noise_bank: np.ndarray, offset: int) -> np.ndarray:
    """An APS frame's read-out: ``img`` (H, W) float64 grey levels plus ``sigma`` (H, W) float64
    (:func:`noise_sigma`) times standard normal noise, rounded and clipped to (H, W) uint8.
    ``noise_bank``: (B,) float32 standard normal values; ``offset``: where this frame's noise
    starts in the bank (0 <= offset <= B - H * W), drawn per frame by the caller."""
    out = np.empty(img.shape, dtype=np.uint8)
    h, w = img.shape
    noise = noise_bank[offset : offset + h * w]
    for y in range(h):
        for x in range(w):
            v = img[y, x] + sigma[y, x] * noise[y * w + x]
            out[y, x] = min(255, max(0, int(math.floor(v + 0.5))))
    return out


def render_frame(
    background: np.ndarray,
    pos: np.ndarray,
    amp: np.ndarray,
    sigma: np.ndarray,
    read_noise: float,
    shot_noise: float,
    noise_bank: np.ndarray,
    offset: int,
) -> np.ndarray:
    """An APS frame: the average of renders over the exposure, plus noise, as uint8
    (:func:`render_exposure`, :func:`noise_sigma`, :func:`read_out`).

    Args:
        background: (H, W) float64 grey levels without markers.
        pos: (S, N, 2) float64 marker positions (image px) at S instants of the exposure.
        amp: (S, N) float64 marker peak brightness above the background (grey levels).
        sigma: (S, N) float64 marker blob sigma (px) at those instants.
        read_noise: sigma of the read noise (grey levels); shot_noise: sigma of the shot noise
            at grey level 1 (it grows with the square root of the grey level).
        noise_bank: (B,) float32 standard normal values; offset: where this frame's noise starts
            in the bank (0 <= offset <= B - H * W), drawn per frame by the caller.
    Returns:
        (H, W) uint8 image.
    """
    img = render_exposure(background, pos, amp, sigma)
    return read_out(img, noise_sigma(img, read_noise, shot_noise), noise_bank, offset)


@numba.njit(cache=True, nogil=True)
def esim_chunk(
    t_us: np.ndarray,
    pos: np.ndarray,
    amp: np.ndarray,
    sigma: np.ndarray,
    start: int,
    img: np.ndarray,
    lin_prev: np.ndarray,
    log_prev: np.ndarray,
    log_ref: np.ndarray,
    last_t: np.ndarray,
    c_on: np.ndarray,
    c_off: np.ndarray,
    rend_pos: np.ndarray,
    rend_amp: np.ndarray,
    rend_sigma: np.ndarray,
    max_step_px: float,
    eps_px: float,
    refractory_us: int,
    out_t: np.ndarray,
    out_x: np.ndarray,
    out_y: np.ndarray,
    out_p: np.ndarray,
    dirty: np.ndarray,
    dirty_list: np.ndarray,
) -> tuple:
    """Generate the events of consecutive intervals [t_us[k], t_us[k+1]] (ESIM).

    Args:
        t_us: (T,) int64 sample times (us), usually 1 ms apart.
        pos: (T, N, 2) float64 marker positions (image px) at those times; amp: (T, N) float64
            marker brightness (grey levels above background); sigma: (T, N) float64 blob sigma (px).
        start: first interval to process.
        img, lin_prev, log_prev, log_ref: (H, W) float64 state: current rendered image (grey
            levels), its value and log when last evaluated, the reference log level of the last
            event.
        last_t: (H, W) int64 time of each pixel's last event (us), for the refractory period.
        c_on, c_off: (H, W) float32 per-pixel contrast thresholds (log units).
        rend_pos (N, 2), rend_amp (N,), rend_sigma (N,): where/how bright/how large each marker is
            currently rendered.
        max_step_px: largest marker motion between two renders (px).
        eps_px: smaller motions of a marker are deferred (not re-rendered yet).
        refractory_us: events of a pixel closer than this to its previous one are dropped.
        out_*: output buffers (timestamp int64, x, y int16, polarity int8), filled from 0.
        dirty (H*W,) uint8, dirty_list (H*W,) int32: scratch.
    Returns:
        (n_events, next_interval): events written; processing stops early (next_interval <
        T - 1) when the buffers may not hold another interval's events -- flush and call again.
    """
    h, w = img.shape
    n_markers = pos.shape[1]
    gx = np.empty(2 * PATCH_RADIUS + 1)
    gy = np.empty(2 * PATCH_RADIUS + 1)
    n_out = 0
    cap = out_t.shape[0]
    k = start
    while k < t_us.shape[0] - 1:
        # worst case of one interval: every patch pixel of every marker crossing many levels
        if cap - n_out < 4 * n_markers * (2 * PATCH_RADIUS + 1) ** 2 * 8:
            break
        t0 = float(t_us[k])
        t1 = float(t_us[k + 1])
        max_move = 0.0
        for n in range(n_markers):
            d = math.hypot(pos[k + 1, n, 0] - pos[k, n, 0], pos[k + 1, n, 1] - pos[k, n, 1])
            if d > max_move:
                max_move = d
        n_sub = max(1, int(math.ceil(max_move / max_step_px)))
        t_prev = t0
        for j in range(1, n_sub + 1):
            a = j / n_sub
            t_now = t0 + a * (t1 - t0)
            n_dirty = np.int64(0)  # not a literal: splat compiles once
            for n in range(n_markers):
                x = pos[k, n, 0] + a * (pos[k + 1, n, 0] - pos[k, n, 0])
                y = pos[k, n, 1] + a * (pos[k + 1, n, 1] - pos[k, n, 1])
                b = amp[k, n] + a * (amp[k + 1, n] - amp[k, n])
                sg = sigma[k, n] + a * (sigma[k + 1, n] - sigma[k, n])
                if (
                    abs(x - rend_pos[n, 0]) < eps_px
                    and abs(y - rend_pos[n, 1]) < eps_px
                    and abs(b - rend_amp[n]) < 0.002 * rend_amp[n]
                    and abs(sg - rend_sigma[n]) < 0.002 * rend_sigma[n]
                ):
                    continue
                n_dirty = splat(
                    img, rend_pos[n, 0], rend_pos[n, 1], -rend_amp[n], rend_sigma[n], dirty, dirty_list, n_dirty, gx, gy
                )
                n_dirty = splat(img, x, y, b, sg, dirty, dirty_list, n_dirty, gx, gy)
                rend_pos[n, 0] = x
                rend_pos[n, 1] = y
                rend_amp[n] = b
                rend_sigma[n] = sg
            dt = t_now - t_prev
            for q in range(n_dirty):
                flat = dirty_list[q]
                dirty[flat] = 0
                yy = flat // w
                xx = flat - yy * w
                if abs(img[yy, xx] - lin_prev[yy, xx]) < SKIP_REL * (lin_prev[yy, xx] + LOG_EPS):
                    continue  # far below any threshold: wait until the change adds up
                lin_prev[yy, xx] = img[yy, xx]
                l_new = math.log(max(img[yy, xx], 0.0) + LOG_EPS)
                l_old = log_prev[yy, xx]
                dl = l_new - l_old
                if dl != 0.0:
                    up = dl > 0.0
                    sign = 1.0 if up else -1.0
                    c = c_on[yy, xx] if up else c_off[yy, xx]
                    while sign * (l_new - log_ref[yy, xx]) >= c:
                        log_ref[yy, xx] += sign * c
                        # a reference already beyond the threshold (its random phase, drawn
                        # within c_on, can lie more than c_off above the level) fires at once
                        te = int(t_prev + max((log_ref[yy, xx] - l_old) / dl, 0.0) * dt)
                        if te - last_t[yy, xx] >= refractory_us:
                            out_t[n_out] = te
                            out_x[n_out] = xx
                            out_y[n_out] = yy
                            out_p[n_out] = 1 if up else 0
                            n_out += 1
                            last_t[yy, xx] = te
                log_prev[yy, xx] = l_new
            t_prev = t_now
        k += 1
    return n_out, k


@numba.njit(cache=True, nogil=True)
def held_still(
    pos: np.ndarray,
    amp: np.ndarray,
    sigma: np.ndarray,
    rend_pos: np.ndarray,
    rend_amp: np.ndarray,
    rend_sigma: np.ndarray,
    eps_px: float,
) -> bool:
    """Whether :func:`esim_chunk` would neither render nor fire over these samples: every sample
    equals the first, and there every marker is within the deferral test of how it is rendered.

    Then each interval has one render (no marker moves), each marker's interpolated state is the
    sample itself (``p + a * 0.0``) and passes the deferral test, so nothing is rendered, no pixel
    is evaluated, no state changes and no event is made: the call can be left out.

    Args:
        pos (T, N, 2), amp (T, N), sigma (T, N): float64 samples as :func:`esim_chunk` takes them.
        rend_pos (N, 2), rend_amp (N,), rend_sigma (N,): float64, how the markers are rendered.
        eps_px: smaller motions are deferred (px).
    """
    for k in range(1, pos.shape[0]):
        for n in range(pos.shape[1]):
            if (
                pos[k, n, 0] != pos[0, n, 0]
                or pos[k, n, 1] != pos[0, n, 1]
                or amp[k, n] != amp[0, n]
                or sigma[k, n] != sigma[0, n]
            ):
                return False
    for n in range(pos.shape[1]):
        if not (
            abs(pos[0, n, 0] - rend_pos[n, 0]) < eps_px
            and abs(pos[0, n, 1] - rend_pos[n, 1]) < eps_px
            and abs(amp[0, n] - rend_amp[n]) < 0.002 * rend_amp[n]
            and abs(sigma[0, n] - rend_sigma[n]) < 0.002 * rend_sigma[n]
        ):
            return False
    return True


def time_ordered(first, noise_t, noise_x, noise_y, noise_p, hot_n, hot_x, hot_y) -> np.ndarray:
    """``first``'s events followed by the noise events, stable-sorted by timestamp, in NumPy
    (a concatenation and NumPy's stable sort; as numba kernels, the concatenation and a mergesort
    cost the simulator's first-run compile ~2.6 s of CPU that a first run's gestures wait for).

    Args:
        first: EVENT_DTYPE events (ESIM's).
        noise_t (M,), noise_p (M,): int64 timestamps (us) and polarities of the noise events:
            the background activity's, then each hot pixel's ``hot_n[i]`` in turn.
        noise_x, noise_y: (B,) int64 pixels of the background activity's B events (px).
        hot_n: (K,) int64 the hot pixels' events' counts; hot_x, hot_y: (K,) int16 the hot
            pixels (px).
    Returns:
        (len(first) + M,) EVENT_DTYPE, the concatenation's stable sort by timestamp.
    Raises:
        ValueError: the counts do not add up (M != B + sum(hot_n)), or the arrays' lengths differ.
    """
    n_first, n_noise, n_activity = len(first), len(noise_t), len(noise_x)
    if (
        len(noise_p) != n_noise
        or len(noise_y) != n_activity
        or not len(hot_n) == len(hot_x) == len(hot_y)
        or n_activity + int(np.sum(hot_n)) != n_noise
        or (len(hot_n) and np.min(hot_n) < 0)
    ):
        raise ValueError("noise events: the counts and the arrays' lengths do not match")
    joined = np.empty(n_first + n_noise, dtype=EVENT_DTYPE)
    joined[:n_first] = first
    noise = joined[n_first:]
    noise["timestamp"], noise["polarity"] = noise_t, noise_p
    noise["x"][:n_activity], noise["y"][:n_activity] = noise_x, noise_y
    noise["x"][n_activity:], noise["y"][n_activity:] = np.repeat(hot_x, hot_n), np.repeat(hot_y, hot_n)
    return joined[np.argsort(joined["timestamp"], kind="stable")]


class EventCamera:
    """The DAVIS-346's event pixels watching the rendered markers (ESIM), with its noise.

    Args:
        background: (H, W) float64 grey levels of the gel without markers.
        rest_px: (N, 2) float64 marker positions (image px) at the start; amp: (N,) brightness;
            sigma: (N,) blob sigma (px).
        rng: numpy Generator (thresholds, reference phases, hot pixels, noise).
        contrast: mean contrast threshold C (log units, default :data:`CONTRAST`); contrast_sigma:
            its per-pixel spread (sigma, log units, default :data:`CONTRAST_SIGMA`). The ON and OFF
            thresholds are drawn per pixel from N(C, sigma), clipped below at C / 2.
        refractory_us: refractory period (us).
        noise_rate_hz: background-activity rate per pixel (Hz, >= 0; default
            :data:`NOISE_RATE_HZ`).
        n_hot: number of hot pixels; hot_rate_hz: their event rate (Hz).
        max_step_px: largest marker motion between two renders (px).
        skip_still: leave ESIM out of :meth:`events` while the markers hold still where they are
            rendered (:func:`held_still`: the same events, sooner); False runs it on every call.
    Raises:
        ValueError: ``noise_rate_hz`` is negative (or NaN).
    """

    def __init__(
        self,
        background: np.ndarray,
        rest_px: np.ndarray,
        amp: np.ndarray,
        sigma: np.ndarray,
        rng: np.random.Generator,
        *,
        contrast: float = CONTRAST,
        contrast_sigma: float = CONTRAST_SIGMA,
        refractory_us: int = 100,
        noise_rate_hz: float = NOISE_RATE_HZ,
        n_hot: int = 4,
        hot_rate_hz: float = 40.0,
        max_step_px: float = 0.25,
        eps_px: float = 0.05,
        skip_still: bool = True,
    ) -> None:
        h, w = background.shape
        self.height, self.width = h, w
        self.sigma = np.ascontiguousarray(sigma, dtype=np.float64)
        self.img = background.astype(np.float64).copy()
        self.rend_pos = np.array(rest_px, dtype=np.float64)
        self.rend_amp = np.array(amp, dtype=np.float64)
        self.rend_sigma = self.sigma.copy()
        no_dirty = np.zeros(0, dtype=np.uint8)
        no_list = np.zeros(0, dtype=np.int32)
        gx, gy = np.empty(2 * PATCH_RADIUS + 1), np.empty(2 * PATCH_RADIUS + 1)
        for n in range(len(self.rend_pos)):
            splat(
                self.img,
                self.rend_pos[n, 0],
                self.rend_pos[n, 1],
                self.rend_amp[n],
                self.sigma[n],
                no_dirty,
                no_list,
                0,
                gx,
                gy,
            )
        self.c_on = np.clip(rng.normal(contrast, contrast_sigma, (h, w)), 0.5 * contrast, None).astype(np.float32)
        self.c_off = np.clip(rng.normal(contrast, contrast_sigma, (h, w)), 0.5 * contrast, None).astype(np.float32)
        self.lin_prev = self.img.copy()
        self.log_prev = np.log(np.maximum(self.img, 0.0) + LOG_EPS)
        # random phase of each pixel's reference within its threshold band
        self.log_ref = self.log_prev + (rng.random((h, w)) - 0.5) * self.c_on
        self.last_t = np.full((h, w), np.iinfo(np.int64).min // 2, dtype=np.int64)
        self.refractory_us = int(refractory_us)
        if not float(noise_rate_hz) >= 0.0:
            raise ValueError(f"noise_rate_hz must be >= 0 Hz per pixel, got {noise_rate_hz}")
        self.noise_rate_hz = float(noise_rate_hz)
        hot = rng.choice(h * w, size=n_hot, replace=False) if n_hot else np.zeros(0, dtype=np.int64)
        self.hot_x = (hot % w).astype(np.int16)
        self.hot_y = (hot // w).astype(np.int16)
        self.hot_rate_hz = float(hot_rate_hz)
        self.max_step_px = float(max_step_px)
        self.eps_px = float(eps_px)
        self.skip_still = bool(skip_still)
        self._no_events = np.zeros(0, dtype=EVENT_DTYPE)
        self._dirty = np.zeros(h * w, dtype=np.uint8)
        self._dirty_list = np.zeros(h * w, dtype=np.int32)
        self._cap = 1 << 20
        self._buf = [
            np.empty(self._cap, dtype=np.int64),
            np.empty(self._cap, dtype=np.int16),
            np.empty(self._cap, dtype=np.int16),
            np.empty(self._cap, dtype=np.int8),
        ]

    def events(
        self,
        t_us: np.ndarray,
        pos: np.ndarray,
        amp: np.ndarray,
        rng: np.random.Generator,
        sigma: np.ndarray | None = None,
    ) -> np.ndarray:
        """Events between t_us[0] (exclusive) and t_us[-1] (inclusive), time-ordered.

        Args:
            t_us: (T,) int64 sample times (us, ~1 ms apart); pos: (T, N, 2) float64 marker
                positions (image px); amp: (T, N) float64 brightness (grey levels); pos[0] must
                continue the previous call's last sample.
            rng: numpy Generator for the noise events.
            sigma: (T, N) float64 blob sigma (px) at t_us (markers that grow); default the
                constructor's sizes.
        Returns:
            EVENT_DTYPE array, stable-sorted by timestamp (polarity 1 = ON).
        """
        pos = np.ascontiguousarray(pos, dtype=np.float64)
        amp = np.ascontiguousarray(amp, dtype=np.float64)
        t_us = np.ascontiguousarray(t_us, dtype=np.int64)
        if sigma is None:
            sigma = np.broadcast_to(self.sigma, amp.shape)
        sigma = np.ascontiguousarray(sigma, dtype=np.float64)
        parts = []
        still = self.skip_still and held_still(
            pos, amp, sigma, self.rend_pos, self.rend_amp, self.rend_sigma, self.eps_px
        )
        k = len(t_us) - 1 if still else 0  # held still: ESIM would make nothing and change nothing
        while k < len(t_us) - 1:
            n, k = esim_chunk(
                t_us,
                pos,
                amp,
                sigma,
                k,
                self.img,
                self.lin_prev,
                self.log_prev,
                self.log_ref,
                self.last_t,
                self.c_on,
                self.c_off,
                self.rend_pos,
                self.rend_amp,
                self.rend_sigma,
                self.max_step_px,
                self.eps_px,
                self.refractory_us,
                *self._buf,
                self._dirty,
                self._dirty_list,
            )
            ev = np.empty(n, dtype=EVENT_DTYPE)
            for name, buf in zip(EVENT_DTYPE.names, self._buf):
                ev[name] = buf[:n]
            parts.append(ev)
        first = self._no_events if not parts else parts[0] if len(parts) == 1 else np.concatenate(parts)
        return time_ordered(first, *self._noise_draws(int(t_us[0]), int(t_us[-1]), rng), self.hot_x, self.hot_y)

    def _noise_draws(
        self, t0_us: int, t1_us: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The noise events' draws in (t0_us, t1_us] (:meth:`noise_events`): timestamps (M,),
        the background activity's pixels x, y (B,), polarities (M,), all int64, and the hot
        pixels' counts (K,) int64."""
        span = t1_us - t0_us
        n_ba = rng.poisson(self.noise_rate_hz * self.width * self.height * span * 1e-6)
        n_hot = rng.poisson(self.hot_rate_hz * span * 1e-6, size=len(self.hot_x))
        n = n_ba + int(n_hot.sum())
        t = rng.integers(t0_us + 1, t1_us + 1, size=n)
        x = rng.integers(0, self.width, size=n_ba)
        y = rng.integers(0, self.height, size=n_ba)
        return t, x, y, rng.integers(0, 2, size=n), n_hot

    def noise_events(self, t0_us: int, t1_us: int, rng: np.random.Generator) -> np.ndarray:
        """Background activity (Poisson, ``noise_rate_hz`` per pixel, random polarity) and hot
        pixels in (t0_us, t1_us]; EVENT_DTYPE, stable-sorted by timestamp."""
        return time_ordered(self._no_events, *self._noise_draws(t0_us, t1_us, rng), self.hot_x, self.hot_y)
