"""Physics families of the simulated gel and camera (``simulate --physics NAME|mix``).

One simulated gel is one model; a real gel is another. To measure how the pipeline generalises,
the simulator draws its gel and camera from named *families*, each changing one aspect of the
default model (:mod:`neurotouch_hid.sources.simulator`) to another published model of it (the
compounds several at once):

============  ==================================================================================
family        what changes, and the model it follows
============  ==================================================================================
default       today's model: Gaussian drag falloff, orthographic camera with one px/mm scale.
powerlaw      long displacement tails: the drag falls off as ``(1 + r^2 / 2 s^2)^(-3/4)``
              (~ r^-1.5) instead of a Gaussian -- between the Gaussian and the 1/r far field of a
              tangential point load on an elastic half-space (Cerruti; Johnson, *Contact
              Mechanics*, 1985, section 3.2).
stickslip     stick/slip contact discs: the surface inside a stick disc of radius ``c`` moves
              rigidly with the finger, a slip annulus ``c < r < a`` lags behind it, and the gel
              outside the contact disc ``a`` follows as ``a / r`` (Cattaneo-Mindlin partial slip,
              ``c = a (1 - Q / mu P)^(1/3)``; Johnson 1985, section 7.2).
indent        normal indentation magnifies markers: the Hertz surface deflection under a
              spherical fingertip (Johnson 1985, section 4.2; ``u_z = delta (1 - r^2 / 2a^2)``
              inside the contact, ``delta/pi [(2 - r^2/a^2) asin(a/r) + sqrt(r^2/a^2 - 1)]``
              outside) brings the markers nearer the camera: their image grows by up to 35 %
              (the positions are unchanged: the pinhole is far compared with the blob size).
camera        a perspective camera under the dome: a pinhole ``CAMERA_MM`` below the base sees a
              surface point at base radius ``rho`` and height ``z`` (the spherical cap) at the
              ray slope ``rho / (D + z)`` -- the rim, nearer the camera, is magnified -- then
              Brown-Conrady radial lens distortion (Brown, "Decentering distortion of lenses",
              1966; ``k1`` barrel) and cos^4 vignetting (natural illumination fall-off, Slama,
              *Manual of Photogrammetry*, 1980). px/mm is no longer uniform: 2.27 px/mm at the
              centre, more towards the rim; the gel's rim still images onto sensor.yaml's circle.
drift         the whole gel moves with the gestures (the dome slides in its mount): up to 1.2 mm
              and 1.2 degrees instead of 0.3 mm and 0.3 degrees.
fingers       finger onset lags (each finger of a gesture starts up to 60 % of the attack after
              the first) and unequal finger strength (each finger 45-100 % of the strongest).
strong        very strong presses: most hold intensities drawn >= 12 mm, and the pressure
              squeezes the markers under a finger together (radial contraction <= 0.6 mm, dimming
              <= 40 %) instead of spreading them.
markers       marker size and brightness spread: blob sigma x lognormal(0, 0.2) and brightness
              x N(1, 0.2) per marker (moulding and paint thickness), clipped to sensible ranges.
noise         a noisy event sensor: background activity 2 Hz per pixel (a DAVIS-346 in dim
              light; Delbruck, Hu, He, "V2E", 2021) and 40 hot pixels at 300 Hz.
flicker       light flicker: the LED ring's brightness follows ``1 + 0.25 sin(2 pi 120 Hz t)``
              (a driver rectifying 60 Hz mains; not locked to the 25 Hz frames, so each APS
              frame's 4 ms exposure sees another phase), in the APS frames and in the markers'
              events (the dark background's flicker stays below the contrast threshold and is
              not rendered as events).
viscoelastic  the gel creeps: a standard linear solid (Zener; a spring in parallel with a Maxwell
              element) under the fingers' load. A finger's pull f(t) (attack, hold, release)
              deforms the gel at once by ``(1 - q) f`` and by a delayed ``q y`` with
              ``tau dy/dt = f - y`` (the SLS's creep compliance ``J(t) = J0 + (J_inf - J0)(1 -
              exp(-t / tau))`` convolved with the load; Findley, Lai & Onaran, *Creep and Relaxation
              of Nonlinear Viscoelastic Materials*, 1976, ch. 5): the deformation keeps growing
              through the hold and, once the fingers have left (the gesture's label ends there),
              relaxes slowly back to rest. q = 0.3, tau = 0.3 s: chosen as a soft silicone's fast
              relaxation, not fitted to a measured gel. Once a held-out family.
pasternak     a gel on a shear-coupled foundation: the drag falls off as the surface deflection of a
              membrane on a Pasternak foundation (Winkler springs coupled by a shear layer) under a
              point load, ``K0(r / lambda)`` (modified Bessel function of the second kind, order 0;
              Kerr, "Elastic and viscoelastic foundation models", J. Appl. Mech. 31, 1964, 491-498),
              regularised over the finger's footprint s (the falloffs' width, widened with the
              displacement as theirs): ``K0(sqrt(r^2 + s^2) / lambda) / K0(s / lambda)``, exactly 1
              at the finger (:func:`pasternak_falloff`). lambda = :data:`PASTERNAK_LAMBDA` s = 1.25
              s, chosen, not fitted: its half-width at half maximum is 1.26 s, 7 % wider than the
              Gaussian's 1.18 s (the power law's: 1.74 s), and its tail lies between the two (at 2 s
              / 3 s / 4 s: 0.26 / 0.11 / 0.044 against the Gaussian's 0.14 / 0.011 / 0.0003 and the
              power law's 0.44 / 0.28 / 0.19; far out ~ exp(-r / lambda) / sqrt(r)); its steepest
              slope, 0.51 / s, is below the Gaussian's 0.61 / s, so the gel folds no more than the
              default's. A development family.
exposure      dim light: the APS frames are exposed for 15 ms of their 40 ms period instead of 4 ms
              (the DAVIS-346's frame exposure is a camera setting, raised by DV's auto-exposure
              when the light is dim; iniVation, DAVIS346 datasheet and DV documentation), so a
              moving marker is blurred over ~4x the distance on the frames. The events, the
              markers' brightness and the labels (at each frame's exposure start, as DV stamps it)
              are unchanged. A development family (once held out).
contrast      an event sensor biased for fewer events: the contrast threshold of the event pixels
              raised from C = 0.25 to 0.45 (log units, ON and OFF alike) with a larger pixel-to-
              pixel mismatch, sigma 0.09 instead of 0.03 (20 % of C instead of 12 %). Users raise
              the ON and OFF event threshold biases (libcaer's bias settings; iniVation, "Biasing
              Dynamic Sensors") to cut background activity and the event rate (Delbruck,
              Graca, Paluch, "Feedback control of event cameras", CVPR Workshops 2021: the rate is
              regulated by threshold control). At nominal bias the mismatch is a few % of
              contrast (2.1 %: Lichtsteiner, Posch, Delbruck, "A 128x128 120 dB 15 us latency
              asynchronous temporal contrast vision sensor", IEEE JSSC 43(2), 2008, 566-576); the
              v2e toolbox's "noisy" DVS parameters draw 25 % of C (0.05 at 0.2; Delbruck, Hu, He,
              "V2E: From video frames to realistic DVS event camera streams", 2020). C and sigma
              chosen, not fitted. A large change of log intensity makes ~0.25 / 0.45 = 0.56x the
              events, a change below the pixel's threshold none (the faint flanks of the markers'
              blobs, small motions), so the tracker sees fewer, sparser events per marker. The
              APS frames, the noise events and the labels are the default family's. The final
              family (``benchmarks/family_eval.py``).
late          late fingers whatever the attack: each finger of a multi-finger gesture but the
              first lands 0-100 ms after it (uniform; at most 0.8 of the attack), however slow
              or fast the attack, where ``fingers`` draws its lags in proportion to the attack. A
              second finger may land ~100 ms after the first (libinput debounces a change of
              finger count for 100 ms; Android's tap timeout is 100 ms). Equal fingers. A
              development family, not in ``mix``.
starts        multi-finger starts as a second, independent simulator's game sessions showed them:
              each finger but the first lands 60-160 ms after it (at most 0.8 of the attack);
              half the multi-finger gestures slide first, every finger on the gel moving
              together by 40-80 % of the gesture's amplitude and back within 20-40 ms, 10-160 ms
              after the start (a push-like moment inside a twist, pinch or zoom); in game
              sessions 60 % of the multi-finger gestures are short taps of 240-360 ms. Equal
              fingers. A development family, not in ``mix``.
compound      several of the above at once, as one real gel and camera may have them: the
              ``pasternak`` falloff, ``indent`` (35 %), the ``camera`` (k1 = -0.10, vignetting),
              the ``markers``' spread, a noisier sensor (1 Hz per pixel, 20 hot pixels at 150
              Hz), the light flickering +-10 % at 120 Hz and ``viscoelastic``'s creep (q 0.3,
              tau 0.3 s). Each effect as its family models it; the mixture chosen, not fitted.
              A development family, not in ``mix``.
compound2     another such gel: the ``powerlaw`` falloff, indent 20 %, the ``camera``, the gel
              sliding up to 0.8 mm and 0.8 degrees, fingers lagging up to 30 % of the attack at
              70-100 % of the strongest's strength, the ``markers``' spread, the noisier sensor of
              ``compound``, a slower, smaller creep (q 0.15, tau 0.5 s) and 8 ms exposures. A
              development family, not in ``mix``.
============  ==================================================================================

``mix`` draws one family per sequence (round robin over a seeded permutation, so that every family
of :data:`MIX_FAMILIES` appears) and writes which one in the dataset's ``physics.json``.

The labels stay the truth of each family: contact points are where the surface points that were
under the finger centres at the gesture's start are now (the largest deformation under each finger
in every family, since every falloff is 1 at the finger), projected by the family's camera into
image px; intensity is their mean displacement in the base plane (mm on the gel, user frame),
whatever the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.sensor import DOME_SPHERE_MM, SensorGeometry

#: Distance of the ``camera`` family's pinhole below the dome's base plane (mm).
CAMERA_MM = 60.0
#: Falloff kinds of the finger drag (gel._finger_field).
FALLOFF_GAUSSIAN, FALLOFF_POWERLAW, FALLOFF_STICKSLIP, FALLOFF_PASTERNAK = 0, 1, 2, 3
#: The ``pasternak`` family's foundation length lambda, in finger footprints s (module docstring).
PASTERNAK_LAMBDA = 1.25


@dataclass(frozen=True)
class Physics:
    """One family of gel and camera models. Defaults are the default family (today's model).

    Attributes:
        name: the family's name (``simulate --physics NAME``).
        falloff: FALLOFF_GAUSSIAN, FALLOFF_POWERLAW, FALLOFF_STICKSLIP or FALLOFF_PASTERNAK.
        indent: relative growth of a marker's image at the centre of a full Hertz indentation.
        perspective: the camera is a pinhole CAMERA_MM below the base, with lens distortion
            ``k1`` (Brown-Conrady, on the ray slope normalised to the rim's) and cos^4 vignetting.
        k1: radial distortion coefficient (negative: barrel).
        global_mm: sigma and clip of the whole gel's translation per gesture (mm);
            global_rad: sigma and clip of its rotation (rad).
        lag: largest onset lag of a finger as a fraction of the attack; lag_ms: largest onset lag
            of a finger in ms whatever the attack (at most 0.8 of it; 0: none); lag_ms_min: the
            smallest such lag of a finger but the first (ms); strength_min:
            weakest finger's strength relative to the strongest (1 = equal fingers).
        strong: fraction of gestures drawn with a hold intensity of 12-20 mm.
        slide: fraction of multi-finger gestures whose fingers first slide together, push-like
            (``SimGesture.slide``).
        short_taps: in game sessions, the fraction of multi-finger gestures made taps, and the
            taps' shortest and longest length (us); empty: the sessions' own taps.
        squeeze: radial contraction of the markers under a pressing finger (mm; 0 = the default
            radial spread of 0.35 mm).
        size_spread: sigma of the log-normal spread of marker blob sizes; brightness_spread: sigma
            of the relative brightness spread (default 0.03).
        noise_hz: background activity per pixel (Hz), or None for the caller's rate.
        n_hot, hot_rate_hz: hot pixels and their rate (Hz).
        flicker: relative amplitude of the light's flicker (0 = steady light); flicker_hz: its frequency.
        creep: the delayed share q of a standard linear solid's deformation (0 = elastic);
            creep_s: its retardation time tau (s).
        exposure_us: the APS frames' exposure (us), or None for the simulator's EXPOSURE_US (4 ms).
        contrast: the event pixels' mean contrast threshold C (log units), or None for the
            camera's :data:`~neurotouch_hid.sources.esim.CONTRAST` (0.25); contrast_sigma: its
            pixel-to-pixel spread (log units), or None for
            :data:`~neurotouch_hid.sources.esim.CONTRAST_SIGMA` (0.03).
    """

    name: str = "default"
    falloff: int = FALLOFF_GAUSSIAN
    indent: float = 0.0
    perspective: bool = False
    k1: float = 0.0
    global_mm: tuple[float, float] = (0.15, 0.3)
    global_rad: tuple[float, float] = (0.003, math.inf)
    lag: float = 0.0
    lag_ms: float = 0.0
    lag_ms_min: float = 0.0
    strength_min: float = 1.0
    strong: float = 0.0
    slide: float = 0.0
    short_taps: tuple[float, int, int] = ()
    squeeze: float = 0.0
    size_spread: float = 0.0
    brightness_spread: float = 0.03
    noise_hz: float | None = None
    n_hot: int = 4
    hot_rate_hz: float = 40.0
    flicker: float = 0.0
    flicker_hz: float = 120.0
    creep: float = 0.0
    creep_s: float = 0.3
    exposure_us: int | None = None
    contrast: float | None = None
    contrast_sigma: float | None = None

    @property
    def changes_gestures(self) -> bool:
        """Whether the family draws gestures differently from the default (its own random stream)."""
        return (
            self.lag > 0
            or self.lag_ms > 0
            or self.strength_min < 1
            or self.strong > 0
            or self.slide > 0
            or bool(self.short_taps)
            or self.global_mm != (0.15, 0.3)
            or self.global_rad != (0.003, math.inf)
        )


#: The named families (module docstring).
PHYSICS: dict[str, Physics] = {
    p.name: p
    for p in (
        Physics(),
        Physics("powerlaw", falloff=FALLOFF_POWERLAW),
        Physics("stickslip", falloff=FALLOFF_STICKSLIP),
        Physics("indent", indent=0.35),
        Physics("camera", perspective=True, k1=-0.10),
        Physics("drift", global_mm=(0.6, 1.2), global_rad=(0.01, 0.021)),
        Physics("fingers", lag=0.6, strength_min=0.45),
        Physics("strong", strong=0.7, squeeze=0.6),
        Physics("markers", size_spread=0.2, brightness_spread=0.2),
        Physics("noise", noise_hz=2.0, n_hot=40, hot_rate_hz=300.0),
        Physics("flicker", flicker=0.25),
        Physics("viscoelastic", creep=0.3, creep_s=0.3),
        Physics("pasternak", falloff=FALLOFF_PASTERNAK),
        Physics("exposure", exposure_us=15_000),
        Physics("contrast", contrast=0.45, contrast_sigma=0.09),
        Physics("late", lag_ms=100.0),
        Physics("starts", lag_ms=160.0, lag_ms_min=60.0, slide=0.5, short_taps=(0.6, 240_000, 360_000)),
        Physics(
            "compound",
            falloff=FALLOFF_PASTERNAK,
            indent=0.35,
            perspective=True,
            k1=-0.10,
            size_spread=0.2,
            brightness_spread=0.2,
            noise_hz=1.0,
            n_hot=20,
            hot_rate_hz=150.0,
            flicker=0.1,
            creep=0.3,
            creep_s=0.3,
        ),
        Physics(
            "compound2",
            falloff=FALLOFF_POWERLAW,
            indent=0.2,
            perspective=True,
            k1=-0.10,
            global_mm=(0.4, 0.8),
            global_rad=(0.006, 0.014),
            lag=0.3,
            strength_min=0.7,
            size_spread=0.2,
            brightness_spread=0.2,
            noise_hz=1.0,
            n_hot=20,
            hot_rate_hz=150.0,
            creep=0.15,
            creep_s=0.5,
            exposure_us=8000,
        ),
    )
}
#: The families ``mix`` draws: every family but ``late`` and the compounds, which came after the
#: mix's sets were measured (drawing them would change every mixed sequence).
MIX_FAMILIES: tuple[str, ...] = tuple(
    name for name in PHYSICS if name not in ("late", "starts", "compound", "compound2")
)
#: ``--physics`` names: every family, and ``mix`` (one family per sequence).
PHYSICS_CHOICES: tuple[str, ...] = (*PHYSICS, "mix")


def physics_family(name: str) -> Physics:
    """The family called ``name``. Raises NeurotouchError (with the choices) for another name."""
    try:
        return PHYSICS[name]
    except KeyError:
        raise NeurotouchError(
            f"unknown physics family {name!r}: expected one of {', '.join(PHYSICS_CHOICES)}"
        ) from None


def mix_families(n_sequences: int, seed: int) -> list[Physics]:
    """One family per sequence for ``--physics mix``: a seeded permutation of
    :data:`MIX_FAMILIES`, repeated, so that ``n_sequences >= len(MIX_FAMILIES)`` covers each."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x9A15]))
    names = list(MIX_FAMILIES)
    order: list[str] = []
    while len(order) < n_sequences:
        order += [names[i] for i in rng.permutation(len(names))]
    return [PHYSICS[n] for n in order[:n_sequences]]


class DomeCamera:
    """How a family's camera images the gel: user-frame mm (base plane) -> image px.

    The default family is orthographic with one scale (:meth:`SensorGeometry.user_to_image`). The
    ``camera`` family is a pinhole ``CAMERA_MM`` below the base looking up the dome's axis: a
    point at base radius rho and height z(rho) on the spherical cap has the ray slope
    u = rho / (D + z), Brown-Conrady distortion makes it u (1 + k1 (u / u_rim)^2), and the image
    radius is scaled so that the base's rim (rho = gel radius, z = 0) lands on sensor.yaml's gel
    circle. Both are radial about the gel centre, so the camera is a radial gain g(rho) applied
    in the user frame before sensor.user_to_image.

    Args:
        sensor: the nominal geometry (sensor.yaml); physics: the family.
    """

    def __init__(self, sensor: SensorGeometry, physics: Physics) -> None:
        self.sensor = sensor
        self.physics = physics
        rb = sensor.gel_radius_mm
        self._rim_u = self._slope(np.array(rb))

    def _height(self, rho: np.ndarray) -> np.ndarray:
        rb = self.sensor.gel_radius_mm
        r = np.minimum(rho, rb)
        return np.sqrt(DOME_SPHERE_MM**2 - r**2) - math.sqrt(DOME_SPHERE_MM**2 - rb**2)

    def _slope(self, rho: np.ndarray) -> np.ndarray:
        """Distorted ray slope (unitless) of base radius rho (mm)."""
        u = rho / (CAMERA_MM + self._height(rho))
        u_rim = self.sensor.gel_radius_mm / CAMERA_MM
        return u * (1.0 + self.physics.k1 * (u / u_rim) ** 2)

    def gain(self, rho: np.ndarray) -> np.ndarray:
        """(...) radial gain g: image radius = g(rho) rho px_per_mm (1 for the default camera)."""
        rho = np.asarray(rho, dtype=np.float64)
        if not self.physics.perspective:
            return np.ones_like(rho)
        small = rho < 1e-9
        safe = np.where(small, 1e-9, rho)
        return self.sensor.gel_radius_mm * self._slope(safe) / self._rim_u / safe

    def project(self, pts_mm: np.ndarray) -> np.ndarray:
        """(..., 2) float64 image px of user-frame points (..., 2) mm."""
        pts_mm = np.asarray(pts_mm, dtype=np.float64)
        if not self.physics.perspective:
            return self.sensor.user_to_image(pts_mm)
        g = self.gain(np.hypot(pts_mm[..., 0], pts_mm[..., 1]))
        return self.sensor.user_to_image(pts_mm * g[..., None])

    def size_gain(self, pts_mm: np.ndarray) -> np.ndarray:
        """(...) how much larger than at the default scale a small dot at pts_mm images: the
        geometric mean of the tangential (g) and radial (d(g rho)/d rho) magnifications."""
        pts_mm = np.asarray(pts_mm, dtype=np.float64)
        rho = np.hypot(pts_mm[..., 0], pts_mm[..., 1])
        if not self.physics.perspective:
            return np.ones_like(rho)
        h = 1e-3
        radial = ((rho + h) * self.gain(rho + h) - np.maximum(rho - h, 0.0) * self.gain(np.maximum(rho - h, 0.0))) / (
            rho + h - np.maximum(rho - h, 0.0)
        )
        return np.sqrt(self.gain(rho) * radial)

    def vignetting_mm(self, pts_mm: np.ndarray) -> np.ndarray:
        """(...) cos^4 of the ray angle of user-frame points (..., 2) mm (1 on the axis)."""
        pts_mm = np.asarray(pts_mm, dtype=np.float64)
        rho = np.hypot(pts_mm[..., 0], pts_mm[..., 1])
        if not self.physics.perspective:
            return np.ones_like(rho)
        u = rho / (CAMERA_MM + self._height(rho))
        return 1.0 / (1.0 + u * u) ** 2

    def vignetting_image(self) -> np.ndarray:
        """(H, W) cos^4 fall-off over the image (1 where the axis meets it), for the background."""
        s = self.sensor
        yy, xx = np.mgrid[0 : s.height, 0 : s.width]
        if not self.physics.perspective:
            return np.ones(xx.shape)
        r_img = np.hypot(xx - s.gel_center_px[0], yy - s.gel_center_px[1]) / s.gel_radius_px
        u = r_img * self._rim_u  # the slope is ~linear in the image radius (distortion aside)
        return 1.0 / (1.0 + u * u) ** 2


@numba.njit(cache=True)
def hertz_deflection(q: float) -> float:
    """Hertz normal surface deflection of a spherical indenter, relative to the indentation
    depth, at q = r / a (distance from the contact's centre over the contact radius, >= 0):
    ``1 - q^2 / 2`` inside, ``[(2 - q^2) asin(1/q) + sqrt(q^2 - 1)] / pi`` outside (Johnson,
    *Contact Mechanics*, 1985, eq. 3.42). 1 at the centre, 1/2 at the edge, ~4 / (3 pi q) far out."""
    if q <= 1.0:
        return 1.0 - 0.5 * q * q
    return ((2.0 - q * q) * math.asin(1.0 / q) + math.sqrt(q * q - 1.0)) / math.pi


@numba.njit(cache=True)
def bessel_k0(x: float) -> float:
    """The modified Bessel function of the second kind, order 0, K0(x) for x > 0 (float64).

    The polynomial approximations of Abramowitz & Stegun, *Handbook of Mathematical Functions*,
    1964: for x <= 2, eq. 9.8.5 (absolute error < 1e-8) with I0(x) from eq. 9.8.1 (relative
    error < 1.6e-7); for x > 2, eq. 9.8.6 (``sqrt(x) e^x K0(x)``, error < 1.9e-7). No SciPy at run
    time. x <= 0 is outside the domain (K0 diverges at 0): the result is not meaningful there.
    """
    if x <= 2.0:
        t = x / 3.75
        t2 = t * t
        i0 = 1.0 + t2 * (
            3.5156229 + t2 * (3.0899424 + t2 * (1.2067492 + t2 * (0.2659732 + t2 * (0.0360768 + t2 * 0.0045813))))
        )
        h2 = 0.25 * x * x
        return -math.log(0.5 * x) * i0 + (
            -0.57721566
            + h2
            * (
                0.42278420
                + h2 * (0.23069756 + h2 * (0.03488590 + h2 * (0.00262698 + h2 * (0.00010750 + h2 * 0.00000740))))
            )
        )
    u = 2.0 / x
    poly = 1.25331414 + u * (
        -0.07832358 + u * (0.02189568 + u * (-0.01062446 + u * (0.00587872 + u * (-0.00251540 + u * 0.00053208))))
    )
    return poly * math.exp(-x) / math.sqrt(x)


#: K0 at the finger (r = 0) of the ``pasternak`` falloff: its normalisation.
_K0_AT_FINGER = bessel_k0.py_func(1.0 / PASTERNAK_LAMBDA)


@numba.njit(cache=True)
def pasternak_falloff(dist2: float, s2: float) -> float:
    """The ``pasternak`` family's drag falloff (module docstring): the regularised surface
    deflection of a Pasternak foundation, ``K0(sqrt(r^2 + s^2) / lambda) / K0(s / lambda)`` with
    lambda = PASTERNAK_LAMBDA s, at squared distance ``dist2`` = r^2 (mm^2) from the finger, for
    the squared footprint ``s2`` = s^2 (mm^2, > 0). 1 at r = 0 (to rounding), decreasing, > 0."""
    return bessel_k0(math.sqrt(dist2 / s2 + 1.0) / PASTERNAK_LAMBDA) / _K0_AT_FINGER


@numba.njit(cache=True)
def sls_deformation(force: np.ndarray, dt_us: float, creep: float, tau_us: float) -> np.ndarray:
    """A standard linear solid's deformation under a load history (module docstring, ``viscoelastic``).

    Args:
        force: (T,) float64 the load (the elastic deformation level it would cause), sampled every
            ``dt_us`` (us) from before the load starts (force[0] = 0 there).
        creep: the delayed share q in [0, 1]; tau_us: the retardation time (us, > 0).
    Returns:
        (T,) float64 ``(1 - q) f + q y`` with ``tau dy/dt = f - y``, y(0) = 0 (exact for a load
        constant over each step). Equal to ``force`` for q = 0; the same steady state as it.
    """
    out = np.empty_like(force)
    decay = math.exp(-dt_us / tau_us)
    y = 0.0
    for k in range(force.shape[0]):
        if k > 0:
            y = y * decay + force[k - 1] * (1.0 - decay)
        out[k] = (1.0 - creep) * force[k] + creep * y
    return out
