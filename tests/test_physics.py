"""Physics families of the simulated gel and camera (sources/physics.py, ``simulate --physics``).

Each family renders (its APS frames show the markers where its own camera puts them) and its labels
are its own truth (the contact points are the largest deformation under each finger, the intensity
the mean displacement of the contacts in mm), checked against the true marker positions the
simulator also returns -- not against the labelling code's own formula.
"""

from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from neurotouch_hid.cli import app
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources.gel import deform
from neurotouch_hid.sources.hands import USERS, draw_gesture, session_gesture
from neurotouch_hid.sources.physics import (
    MIX_FAMILIES,
    PASTERNAK_LAMBDA,
    PHYSICS,
    DomeCamera,
    bessel_k0,
    hertz_deflection,
    mix_families,
    pasternak_falloff,
)
from neurotouch_hid.sources.simulator import START_US, GelSimulator

SENSOR = SensorGeometry()


def _gesture(kind: GestureType, fingers_mm, amplitude=6.0, **extra):
    g = draw_gesture(np.random.default_rng(1), USERS[0], kind, START_US + 80_000, SENSOR)
    fingers = np.asarray(fingers_mm, dtype=np.float64)
    return dataclasses.replace(
        g,
        fingers_mm=fingers,
        amplitude_mm=amplitude,
        direction=np.array([1.0, 0.0]),
        attack_us=200_000,
        hold_us=600_000,
        release_us=200_000,
        press=0.8,
        tremor=(0.0, 5.0, 0.0),
        global_mm=np.zeros(2),
        global_rad=0.0,
        **extra,
    )


def _blobs(frame: np.ndarray) -> np.ndarray:
    """(M, 2) intensity-weighted centroids (px) of the bright blobs of an APS frame (OpenCV)."""
    mask = (frame > 55).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    img = frame.astype(np.float64) - 20.0
    out = []
    yy, xx = np.mgrid[0 : frame.shape[0], 0 : frame.shape[1]]
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < 2:
            continue
        m = lab == k
        w = np.clip(img[m], 0, None)
        out.append([(xx[m] * w).sum() / w.sum(), (yy[m] * w).sum() / w.sum()])
    return np.array(out)


def _run(sim: GelSimulator, frames: int):
    return [sim.step() for _ in range(frames)]


@pytest.mark.parametrize("name", list(PHYSICS))
def test_family_renders_markers_where_its_camera_puts_them(name):
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[], physics=PHYSICS[name])
    chunk = sim.step()
    blobs = _blobs(chunk.frame.image)
    rest = sim.gel.rest_px
    assert len(rest) == 177
    d = np.linalg.norm(rest[:, None] - blobs[None], axis=-1).min(axis=1)
    assert np.mean(d < 0.5) > 0.95, (name, np.percentile(d, [50, 90, 100]))


@pytest.mark.parametrize("name", list(PHYSICS))
def test_family_labels_are_the_largest_deformation_under_each_finger(name):
    physics = PHYSICS[name]
    extra = {}
    if physics.lag > 0:
        extra["lags_us"] = (0, 120_000)
    if physics.strength_min < 1:  # the second finger as weak as the family draws it
        extra["strengths"] = (1.0, physics.strength_min)
    if physics.squeeze > 0:
        extra["squeeze"] = physics.squeeze
    if physics.creep > 0:
        extra["sls"] = (physics.creep, int(physics.creep_s * 1e6))
    g = _gesture(GestureType.PINCH, [[-7.0, 2.0], [7.0, 2.0]], amplitude=4.0, **extra)
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=physics)
    chunks = _run(sim, 14)  # rest, attack, into the hold (START_US + 80 ms + 200 ms attack)
    checked = 0
    for chunk in chunks:
        label = chunk.label
        if label.gesture is not GestureType.PINCH:
            continue
        t = np.array([label.t_us], dtype=np.int64)
        pos_px, _, _, pos_mm = sim.marker_state(t, [g])
        moved_mm = np.linalg.norm(pos_mm[0] - sim.gel.rest_mm, axis=-1)
        assert np.allclose(pos_px[0], chunk.positions_px[0], atol=1e-3)  # the same truth the files hold
        per_finger = []
        for k, contact in enumerate(label.contacts_px):
            # markers that rested under finger k (within its footprint)
            near = np.linalg.norm(sim.gel.rest_mm - g.fingers_mm[k], axis=-1) < 4.0
            best = np.flatnonzero(near)[np.argmax(moved_mm[near])]
            per_finger.append(moved_mm[best])
            if moved_mm[best] > 0.5:
                # the label sits on the largest deformation: within a marker pitch of that marker
                pitch_px = 4.0 * SENSOR.px_per_mm * float(sim.gel.camera.size_gain(sim.gel.rest_mm[best]))
                assert np.linalg.norm(contact - pos_px[0, best]) < pitch_px, (name, k)
        truth = float(np.mean(per_finger))
        assert abs(label.intensity_mm - truth) <= 0.2 * truth + 0.15, (name, label.intensity_mm, truth)
        checked += 1
    assert checked >= 5


def test_camera_family_has_non_uniform_px_per_mm_and_keeps_the_gel_circle():
    cam = DomeCamera(SENSOR, PHYSICS["camera"])
    flat = DomeCamera(SENSOR, PHYSICS["default"])

    # local scale (px per mm) at the centre and near the rim, radially
    def scale(c, rho):
        a, b = c.project(np.array([[rho, 0.0]])), c.project(np.array([[rho + 0.5, 0.0]]))
        return float(np.linalg.norm(b - a)) / 0.5

    assert scale(flat, 0.0) == pytest.approx(SENSOR.px_per_mm)
    assert scale(flat, 25.0) == pytest.approx(SENSOR.px_per_mm)
    assert scale(cam, 0.0) < 0.95 * SENSOR.px_per_mm
    assert scale(cam, 25.0) > 1.2 * scale(cam, 0.0)
    rim = cam.project(np.array([[SENSOR.gel_radius_mm, 0.0]]))[0]
    assert np.linalg.norm(rim - np.asarray(SENSOR.gel_center_px)) == pytest.approx(SENSOR.gel_radius_px)
    # cos^4 vignetting: markers fade towards the rim
    assert cam.vignetting_mm(np.array([[0.0, 0.0]]))[0] == 1.0
    assert 0.6 < cam.vignetting_mm(np.array([[27.0, 0.0]]))[0] < 0.8


def test_hertz_deflection_is_continuous_at_the_contact_edge():
    assert hertz_deflection(0.0) == 1.0
    assert hertz_deflection(1.0 - 1e-9) == pytest.approx(0.5) and hertz_deflection(1.0 + 1e-9) == pytest.approx(
        0.5, abs=1e-4
    )
    assert hertz_deflection(10.0) == pytest.approx(4.0 / (3.0 * math.pi * 10.0), rel=0.02)  # the far field


def test_indent_family_magnifies_markers_under_the_finger_only():
    g = _gesture(GestureType.PUSH, [[0.0, 0.0]], amplitude=3.0)
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=PHYSICS["indent"])
    t = np.array([g.t_start_us + g.attack_us + 100_000], dtype=np.int64)
    _, _, sigma, _ = sim.marker_state(t, [g])
    grow = sigma[0] / sim.gel.sigma_px
    r = np.linalg.norm(sim.gel.rest_mm, axis=-1)
    assert grow[r < 2.0].min() > 1.2
    # Hertz's deflection outside the contact falls off ~ a / r: a fifth of the centre's at 20 mm
    assert grow[r > 20.0].max() - 1.0 < 0.25 * (grow[r < 2.0].min() - 1.0)
    default = GelSimulator(SENSOR, USERS[0], seed=3, script=[g])
    assert np.allclose(default.marker_state(t, [g])[2][0], default.gel.sigma_px)


def _one_finger_push_moves(names: tuple[str, ...]) -> tuple[dict, np.ndarray]:
    """How far (mm) each marker moved under a 4 mm one-finger push at the gel's centre, per family
    in ``names``, and each marker's distance (mm) from the centre at rest."""
    g = _gesture(GestureType.PUSH, [[0.0, 0.0]], amplitude=4.0)
    t = np.array([g.t_start_us + g.attack_us + 100_000], dtype=np.int64)
    moved = {}
    for name in names:
        sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=PHYSICS[name])
        pos_mm = sim.marker_state(t, [g])[3][0]
        moved[name] = np.linalg.norm(pos_mm - sim.gel.rest_mm, axis=-1)
    return moved, np.linalg.norm(GelSimulator(SENSOR, script=[]).gel.rest_mm, axis=-1)


def test_falloff_families_differ_in_their_tails_and_stick_disc():
    moved, r = _one_finger_push_moves(("default", "powerlaw", "stickslip"))
    far = (r > 16.0) & (r < 20.0)
    assert moved["powerlaw"][far].mean() > 2.0 * moved["default"][far].mean()
    assert moved["stickslip"][far].mean() > 2.0 * moved["default"][far].mean()
    # the stick disc moves rigidly with the finger (the Gaussian already lags 4 mm away)
    ring = (r > 3.5) & (r < 4.5)
    assert np.allclose(moved["stickslip"][ring], 4.0, atol=0.4)
    assert moved["default"][ring].max() < 3.8


def test_gesture_families_draw_strong_presses_lags_unequal_fingers_and_drift():
    def draws(name, kind=GestureType.PUSH):
        rng, prng = np.random.default_rng(5), np.random.default_rng(6)
        return [draw_gesture(rng, USERS[0], kind, 0, SENSOR, PHYSICS[name], prng) for _ in range(40)]

    strong = [g.amplitude_mm for g in draws("strong")]
    assert np.mean(np.array(strong) >= 12.0) > 0.5
    assert np.mean(np.array(strong) >= 12.0) > 3 * np.mean(np.array([g.amplitude_mm for g in draws("default")]) >= 12.0)
    fingers = draws("fingers", GestureType.PINCH)
    assert all(len(g.lags_us) == len(g.fingers_mm) and min(g.lags_us) == 0 for g in fingers)
    assert max(max(g.lags_us) for g in fingers) > 0.3 * max(g.attack_us for g in fingers) * 0.5
    assert min(min(g.strengths) for g in fingers) < 0.6
    drift = [np.linalg.norm(g.global_mm) for g in draws("drift")]
    assert max(drift) > 0.6 >= max(np.linalg.norm(g.global_mm) for g in draws("default"))
    # a lagging finger has not moved yet while the first one has
    g = fingers[int(np.argmax([max(f.lags_us) for f in fingers]))]
    late = int(np.argmax(g.lags_us))
    levels = g.finger_levels(np.array([g.t_start_us + g.lags_us[late] // 2], dtype=np.int64))[0]
    assert levels[late] == 0.0 and levels.max() > 0.0


def test_late_fingers_land_up_to_100_ms_after_the_first_however_slow_the_attack():
    """``late``: lags uniform in 0-100 ms (at most 0.8 of the attack), where ``fingers`` draws
    them in proportion to the attack; a tap keeps its late finger's lag when it fits."""

    def draws(name, user):
        rng, prng = np.random.default_rng(5), np.random.default_rng(6)
        return [draw_gesture(rng, USERS[user], GestureType.TWIST_CW, 0, SENSOR, PHYSICS[name], prng) for _ in range(60)]

    late = draws("late", 0) + draws("late", 4)
    assert all(len(g.lags_us) == len(g.fingers_mm) and min(g.lags_us) == 0 for g in late)
    assert all(max(g.lags_us) <= min(100_000, 0.8 * g.attack_us) for g in late)
    slow = [g for g in late if g.attack_us > 400_000]
    assert slow and max(max(g.lags_us) for g in slow) > 80_000  # as late on a slow attack as the cap allows
    fingers = [g for g in draws("fingers", 0) + draws("fingers", 4) if g.attack_us > 400_000]
    assert max(max(g.lags_us) for g in fingers) > 150_000  # in proportion: far later than 100 ms
    assert not draws("default", 0)[0].lags_us  # the default family's fingers land together

    taps = []
    for seed in range(40):
        rng, prng = np.random.default_rng(seed), np.random.default_rng(seed + 100)
        kinds = [GestureType.PINCH]
        taps.append(session_gesture(rng, USERS[0], kinds, None, 0, SENSOR, PHYSICS["late"], prng))
    short = [g for g in taps if g.attack_us + g.hold_us + g.release_us <= 500_000]
    assert short and all(max(g.lags_us) <= 0.8 * g.attack_us for g in short)
    assert max(max(g.lags_us) for g in short) > 50_000  # not shrunk with the tap's attack


def test_starts_late_second_fingers_a_push_like_slide_and_short_multi_finger_taps():
    """``starts``: fingers but the first land 60-160 ms late (at most 0.8 of the attack); about half
    the multi-finger gestures slide first (every finger on the gel moving together, push-like, for
    20-40 ms, 10-160 ms in), which moves the labelled contacts, and pushes never slide; in game
    sessions most multi-finger gestures are taps of 240-360 ms."""
    rng, prng = np.random.default_rng(5), np.random.default_rng(6)
    twists = [draw_gesture(rng, USERS[0], GestureType.TWIST_CW, 0, SENSOR, PHYSICS["starts"], prng) for _ in range(60)]
    second = [sorted(g.lags_us)[1] for g in twists]
    assert all(
        min(60_000, 0.8 * g.attack_us) <= lag <= min(160_000, 0.8 * g.attack_us) + 1 for g, lag in zip(twists, second)
    )
    slid = [g for g in twists if g.slide]
    assert 0.3 < len(slid) / len(twists) < 0.7
    assert all(10_000 <= g.slide[0] <= 160_000 and 20_000 <= g.slide[1] <= 40_000 for g in slid)
    g = slid[0]
    t = np.array([g.t_start_us + g.slide[0] + g.slide[1] // 2], dtype=np.int64)
    common = g.slide_displacement(t)[0]
    assert np.hypot(*common) == pytest.approx(np.hypot(g.slide[2], g.slide[3]))
    with_slide = deform([g], g.fingers_mm, t, SENSOR.gel_radius_mm, PHYSICS["starts"])[0][0]
    without = deform([dataclasses.replace(g, slide=())], g.fingers_mm, t, SENSOR.gel_radius_mm, PHYSICS["starts"])[0][0]
    on = g.finger_levels(t)[0] > 0
    assert np.allclose((with_slide - without)[on], common, atol=0.05 * np.hypot(*common))
    pushes = [draw_gesture(rng, USERS[0], GestureType.PUSH, 0, SENSOR, PHYSICS["starts"], prng) for _ in range(30)]
    assert not any(p.slide for p in pushes)
    taps = []
    for seed in range(40):
        rng, prng = np.random.default_rng(seed), np.random.default_rng(seed + 100)
        taps.append(session_gesture(rng, USERS[0], [GestureType.PINCH], None, 0, SENSOR, PHYSICS["starts"], prng))
    lengths = [g.attack_us + g.hold_us + g.release_us for g in taps]
    short = [n for n in lengths if 240_000 <= n <= 360_000]
    assert len(short) / len(taps) > 0.45


def test_viscoelastic_gel_creeps_under_a_hold_and_relaxes_slowly_after_release():
    """The standard linear solid: 70 % of the load's deformation at once, the rest with tau = 0.3 s;
    after the release the gel is still deformed (labelled none, not resting, until every marker is
    back within 0.1 mm) long after the elastic gel has settled."""
    physics = PHYSICS["viscoelastic"]
    assert draw_gesture(np.random.default_rng(5), USERS[0], GestureType.PUSH, 0, SENSOR, physics).sls == (0.3, 300_000)
    g = _gesture(GestureType.PUSH, [[0.0, 0.0]], amplitude=5.0, sls=(physics.creep, int(physics.creep_s * 1e6)))
    elastic = dataclasses.replace(g, sls=())
    hold0, hold1 = g.t_start_us + g.attack_us, g.t_start_us + g.attack_us + g.hold_us
    t = np.array([hold0, hold1 - 1000, g.t_end_us + 300_000], dtype=np.int64)
    creep, flat = g.profile(t), elastic.profile(t)
    assert flat[0] == pytest.approx(1.0, abs=0.01) and flat[1] == pytest.approx(1.0, abs=0.01)
    assert 0.75 < creep[0] < 0.9 and creep[1] > max(0.95, creep[0] + 0.15)  # grows through the hold (2 tau)
    assert flat[2] < 0.01 and creep[2] > 0.05  # 300 ms after the release: still deformed
    assert g.t_settled_us - g.t_end_us >= 7 * 300_000  # the simulator keeps the gesture until it relaxed
    # the labels: none after the release, not resting while the slow relaxation is above 0.1 mm
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=physics)
    after = [c.label for c in _run(sim, 60) if c.label.t_us >= g.t_end_us]
    assert all(lab.gesture is GestureType.NONE for lab in after)
    assert not after[0].resting and not after[5].resting  # 200 ms after the release
    assert after[-1].resting  # ~1.2 s after: back within 0.1 mm
    pos = sim.marker_state(np.array([g.t_end_us + 200_000], dtype=np.int64), [g])[3][0]
    assert np.linalg.norm(pos - sim.gel.rest_mm, axis=-1).max() > 0.3


def _k0_integral(x: float) -> float:
    """K0(x) from its integral representation int_0^inf exp(-x cosh t) dt (Abramowitz & Stegun
    9.6.24), by NumPy's trapezoid rule: another route than the polynomial approximations."""
    t = np.linspace(0.0, 12.0, 40_001)  # x cosh(12) > 4000 for x >= 0.05: the rest is negligible
    return float(np.trapezoid(np.exp(-x * np.cosh(t)), t))


@pytest.mark.parametrize("x", [0.05, 0.3, 0.8, 1.5, 1.999, 2.0, 2.001, 3.5, 6.0, 10.0])
def test_bessel_k0_matches_its_integral_representation(x):
    assert bessel_k0(x) == pytest.approx(_k0_integral(x), rel=1e-6)


def test_pasternak_falloff_is_one_at_the_finger_and_lies_between_the_gaussian_and_the_power_law():
    for s in (6.0, 7.0, 11.5):
        assert pasternak_falloff(0.0, s * s) == pytest.approx(1.0, abs=1e-12)
    s = 7.0
    lam = PASTERNAK_LAMBDA * s
    for q in (0.5, 1.0, 2.0, 3.0, 5.0, 8.0):  # the K0 ratio of the regularised point load
        expected = _k0_integral(math.hypot(q * s, s) / lam) / _k0_integral(s / lam)
        assert pasternak_falloff((q * s) ** 2, s * s) == pytest.approx(expected, rel=1e-5)
    radii = np.linspace(0.0, 40.0, 401)
    w = np.array([pasternak_falloff(r * r, s * s) for r in radii])
    assert np.all(np.diff(w) < 0) and w[-1] > 0
    # its half-width at half maximum within 30 % of the Gaussian's (s sqrt(2 ln 2)) ...
    lo, hi = 0.0, 40.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pasternak_falloff(mid * mid, s * s) > 0.5 else (lo, mid)
    assert 0.7 < lo / (s * math.sqrt(2.0 * math.log(2.0))) < 1.3
    # ... and its tail between the Gaussian's and the power law's
    for q in (2.0, 3.0, 4.0, 5.0):
        gaussian, power = math.exp(-q * q / 2.0), (1.0 + q * q / 2.0) ** -0.75
        assert 1.5 * gaussian < pasternak_falloff((q * s) ** 2, s * s) < power / 1.5, q


def test_pasternak_gel_drags_between_the_gaussian_and_the_power_law():
    moved, r = _one_finger_push_moves(("default", "powerlaw", "pasternak"))
    assert moved["pasternak"][r < 0.5] == pytest.approx(4.0, abs=0.05)  # the finger's own marker
    for band in ((12.0, 16.0), (16.0, 20.0)):
        far = (r > band[0]) & (r < band[1])
        assert 1.3 * moved["default"][far].mean() < moved["pasternak"][far].mean(), band
        assert moved["pasternak"][far].mean() < moved["powerlaw"][far].mean() / 1.3, band


def test_default_family_draws_do_not_change_when_other_families_exist():
    a = draw_gesture(np.random.default_rng(9), USERS[2], GestureType.ZOOM, 0, SENSOR)
    b = draw_gesture(
        np.random.default_rng(9), USERS[2], GestureType.ZOOM, 0, SENSOR, PHYSICS["markers"], np.random.default_rng(1)
    )
    assert a.amplitude_mm == b.amplitude_mm and np.array_equal(a.fingers_mm, b.fingers_mm)
    assert a.press == b.press and a.creep_us == b.creep_us and np.array_equal(a.global_mm, b.global_mm)


def _rest_events(name: str) -> int:
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[], physics=PHYSICS[name])
    return sum(len(c.events) for c in _run(sim, 5))


def test_noise_and_flicker_families_add_events_at_rest():
    quiet = _rest_events("default")
    assert _rest_events("noise") > 10 * max(quiet, 1)
    assert _rest_events("flicker") > 10 * max(quiet, 1)


def test_flicker_changes_aps_brightness_and_markers_family_spreads_marker_sizes():
    sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[], physics=PHYSICS["flicker"])
    means = [
        float(c.frame.image[sim.gel.rest_px[:, 1].astype(int), sim.gel.rest_px[:, 0].astype(int)].mean())
        for c in _run(sim, 8)
    ]
    assert max(means) - min(means) > 5.0
    spread = GelSimulator(SENSOR, USERS[0], seed=3, script=[], physics=PHYSICS["markers"]).gel
    plain = GelSimulator(SENSOR, USERS[0], seed=3, script=[]).gel
    assert np.std(spread.sigma_px / plain.sigma_px) > 0.1
    assert np.std(spread.brightness / plain.brightness) > 0.1


def test_mix_covers_every_family_and_simulate_writes_physics_json(tmp_path):
    fams = mix_families(len(MIX_FAMILIES), seed=4)
    assert sorted(f.name for f in fams) == sorted(MIX_FAMILIES)
    assert set(PHYSICS) - set(MIX_FAMILIES) == {
        "late",
        "starts",
        "compound",
        "compound2",
    }  # drawn by no mix: none changed
    assert "late" not in {f.name for f in mix_families(300, seed=2)}
    out = tmp_path / "mix"
    result = CliRunner().invoke(
        app, ["simulate", "--out", str(out), "--physics", "mix", "--minutes", "0.05", "--users", "0"]
    )
    assert result.exit_code == 0, result.output
    data = json.loads((out / "physics.json").read_text())
    assert data["physics"] == "mix"
    assert set(data["sequences"]) == {f"u0_{g}" for g in ("push", "pinch", "zoom", "twist_cw", "twist_ccw")}
    assert set(data["sequences"].values()) <= set(PHYSICS)
    assert all((out / f"{name}.labels.csv").exists() for name in data["sequences"])


def test_unknown_physics_family_is_one_clear_error(tmp_path, monkeypatch, capsys):
    from neurotouch_hid.cli import main

    monkeypatch.setattr("sys.argv", ["neurotouch-hid", "simulate", "--out", str(tmp_path / "x"), "--physics", "jelly"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unknown physics family 'jelly'" in err and "mix" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("families", ["contrast", "default,contrast", "powerlaw,mix"])
def test_family_eval_refuses_the_final_families_without_final_run(tmp_path, families):
    """The protocol (docs/accuracy.md): the final family (``FINAL_FAMILY``, contrast) and the mix, which
    draws it, are evaluated only with --final-run; nothing is simulated or written before the
    refusal."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "family_eval.py"
    out = tmp_path / "families"
    run = subprocess.run(
        [sys.executable, str(script), "--out", str(out), "--families", families],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert "add --final-run" in " ".join(run.stderr.split()) and "contrast" in run.stderr
    assert not out.exists()


@pytest.mark.parametrize("families", ["contrast", "default,mix"])
def test_classifier_training_refuses_the_final_family_and_mix(tmp_path, families):
    """train_gesture_classifier.py never trains on the final family (family_eval.FINAL_FAMILY,
    contrast) nor on mix, which draws it: exit 2 before anything is simulated."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "train_gesture_classifier.py"
    out, test = tmp_path / "train", tmp_path / "test"
    run = subprocess.run(
        [sys.executable, str(script), "--out", str(out), "--test", str(test), "--families", families],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert "contrast is the final family" in " ".join(run.stderr.split())
    assert not out.exists() and not test.exists()


def test_exposure_family_blurs_a_moving_marker_over_15_ms_and_keeps_the_events():
    """Dim light (``exposure``): a frame shows a moving marker at its mean position over the 15 ms
    exposure (the default: over 4 ms), ahead of where it was at the frame's timestamp (the
    exposure's start); the events are the default family's."""
    g = _gesture(GestureType.PUSH, [[0.0, 0.0]], amplitude=6.0)
    sims = {
        name: GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=PHYSICS[name])
        for name in ("default", "exposure")
    }
    chunks = {name: _run(sim, 8) for name, sim in sims.items()}
    for a, b in zip(chunks["default"], chunks["exposure"]):
        assert np.array_equal(a.events, b.events)
    mid = g.t_start_us + g.attack_us // 2
    k = int(np.argmin([abs(c.frame.t_us - mid) for c in chunks["default"]]))
    t0 = chunks["default"][k].frame.t_us
    centre = int(np.argmin(np.linalg.norm(sims["default"].gel.rest_mm, axis=-1)))
    ahead = {}
    for name, exposure_us in (("default", 4_000), ("exposure", 15_000)):
        times = np.arange(t0, t0 + exposure_us + 1, 100, dtype=np.int64)
        path = sims[name].marker_state(times, [g])[0][:, centre]
        blobs = _blobs(chunks[name][k].frame.image)
        seen = blobs[np.argmin(np.linalg.norm(blobs - path.mean(axis=0), axis=1))]
        assert np.linalg.norm(seen - path.mean(axis=0)) < 0.1, name  # the exposure's mean position
        ahead[name] = float(np.linalg.norm(seen - path[0]))
    assert ahead["exposure"] > 0.6 and ahead["exposure"] > 3.0 * ahead["default"]


def test_contrast_family_makes_fewer_marker_events_and_keeps_frames_and_labels():
    """An event sensor biased for fewer events (``contrast``): per-pixel ON and OFF thresholds of
    mean 0.45 and spread 0.09 (log units; the default camera's 0.25 and 0.03). A pixel whose log
    intensity moves by |dL| >> C makes ~|dL| / C events, so on the same gesture the markers make
    at most ~E[1/c] at 0.45 over E[1/c] at 0.25 = 0.25 / 0.45 x (1 + 0.2^2) / (1 + 0.12^2) ~ 0.57
    of the default's events, fewer where the change stays below the higher threshold (the blobs'
    faint flanks, which then fire in no pixel at all). The APS frames, the true marker positions
    and the labels are the default family's; so is the noise."""
    g = _gesture(GestureType.PUSH, [[0.0, 0.0]], amplitude=6.0)
    chosen = {"default": (0.25, 0.03), "contrast": (0.45, 0.09)}
    chunks, marker_events, pixels = {}, {}, {}
    for name, (mean, sigma) in chosen.items():
        sim = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], physics=PHYSICS[name])
        for c in (sim.camera.c_on, sim.camera.c_off):  # 346 x 260 draws: within ~1 % of the chosen figures
            assert float(c.mean()) == pytest.approx(mean, abs=0.005), name
            assert float(c.std()) == pytest.approx(sigma, rel=0.05), name
        chunks[name] = _run(sim, 8)  # rest, then the 200 ms attack
        # the markers alone: no background activity; the hot pixels' events left out
        quiet = GelSimulator(SENSOR, USERS[0], seed=3, script=[g], noise_rate_hz=0.0, physics=PHYSICS[name])
        ev = np.concatenate([c.events for c in _run(quiet, 8)])
        hot = set(zip(quiet.camera.hot_x.tolist(), quiet.camera.hot_y.tolist()))
        marker = np.array([(x, y) not in hot for x, y in zip(ev["x"].tolist(), ev["y"].tolist())], dtype=bool)
        marker_events[name] = int(marker.sum())
        pixels[name] = len(set(zip(ev["x"][marker].tolist(), ev["y"][marker].tolist())))
    assert marker_events["default"] > 5000  # the push moved the markers
    ratio = marker_events["contrast"] / marker_events["default"]
    assert 0.3 < ratio < 0.62, ratio
    assert pixels["contrast"] < 0.95 * pixels["default"], pixels
    for a, b in zip(chunks["default"], chunks["contrast"]):
        assert a.frame.t_us == b.frame.t_us and np.array_equal(a.frame.image, b.frame.image)
        assert np.array_equal(a.positions_px, b.positions_px)
        la, lb = a.label, b.label
        assert (la.t_us, la.gesture, la.resting, la.intensity_mm) == (lb.t_us, lb.gesture, lb.resting, lb.intensity_mm)
        assert np.array_equal(la.contacts_px, lb.contacts_px)
    rest = [k for k, c in enumerate(chunks["default"]) if c.frame.t_us + 40_000 <= g.t_start_us]
    assert rest and all(np.array_equal(chunks["default"][k].events, chunks["contrast"][k].events) for k in rest)
    assert sum(c.label.gesture is GestureType.PUSH for c in chunks["contrast"]) >= 5
