"""Game sessions in the simulator (``simulate --preset sessions``): the type changes from one
gesture to the next, taps from 0.25 s, ordinary gestures, holds of several seconds and rests of
a fraction of a second, on every physics family; labels as docs/dataset.md defines them."""

from __future__ import annotations

import csv
import itertools
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from neurotouch_hid.cli import app
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources.gel import SimGesture
from neurotouch_hid.sources.hands import MAX_SPEED_MM_S, USERS, gesture_script
from neurotouch_hid.sources.physics import PHYSICS


def session(family: str, user: int, n: int = 60) -> list[SimGesture]:
    script = gesture_script(
        np.random.default_rng(user),
        USERS[user],
        list(GestureType)[1:],
        1_000_000,
        SensorGeometry(),
        physics=PHYSICS[family],
        physics_rng=np.random.default_rng(100 + user),
        session=True,
    )
    return list(itertools.islice(script, n))


@pytest.mark.parametrize("family", list(PHYSICS))
def test_a_session_changes_type_with_taps_holds_and_short_rests(family):
    gestures = [g for user in (0, 4, 7) for g in session(family, user)]
    for user in (0, 4, 7):
        kinds = [g.gesture for g in session(family, user)]
        assert all(a is not b for a, b in zip(kinds, kinds[1:])), "the type changes from one gesture to the next"
        assert set(kinds) == set(list(GestureType)[1:])
        s = session(family, user)
        rests = [(b.t_start_us - a.t_end_us) / 1e6 for a, b in zip(s, s[1:])]
        assert all(0.15 <= r <= 0.7 for r in rests), "rests of a fraction of a second"
    lengths = [(g.t_end_us - g.t_start_us) / 1e6 for g in gestures]
    taps = [g for g, d in zip(gestures, lengths) if d <= 0.5]
    shortest = PHYSICS[family].short_taps[1] / 1e6 if PHYSICS[family].short_taps else 0.25  # ``starts``: 0.24 s
    assert taps and min(lengths) >= shortest, f"taps, none shorter than {shortest} s"
    assert any(g.hold_us >= 2_500_000 for g in gestures), "holds of several seconds"
    assert any(0.5 < d and g.hold_us < 2_500_000 for g, d in zip(gestures, lengths)), "ordinary gestures"
    for g in gestures:
        # the cosine attack's peak speed (pi A / 2 T) stays a human's, and a late finger still lands in it
        assert math.pi * g.amplitude_mm / (2 * g.attack_us * 1e-6) <= MAX_SPEED_MM_S + 1e-6
        assert all(0 <= lag < g.attack_us for lag in g.lags_us)
    if PHYSICS[family].lag > 0:
        assert any(max(g.lags_us) > 0 for g in taps), "a tap's second finger may land late too"


def test_simulate_sessions_writes_labelled_sessions(tmp_path):
    out = tmp_path / "sessions"
    result = CliRunner().invoke(
        app, ["simulate", "--out", str(out), "--preset", "sessions", "--users", "3", "--seed", "2", "--physics", "mix"]
    )
    assert result.exit_code == 0, result.output
    assert json.loads((out / "physics.json").read_text())["sequences"].keys() == {"u3_session0"}
    with open(out / "u3_session0.labels.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    times = [int(r["t_us"]) for r in rows]
    assert times[-1] - times[0] >= 10_000_000 - 40_000 and rows[-1]["resting"] == "1"
    runs = [(k, list(g)) for k, g in itertools.groupby(rows, key=lambda r: r["gesture"])]
    gestures = [(k, g) for k, g in runs if k != "none"]
    assert len(gestures) >= 3
    kinds = [k for k, _ in gestures]
    assert all(a != b for a, b in zip(kinds, kinds[1:])), kinds
    for _, frames in gestures:  # docs/dataset.md: not resting, contacts filled as counted
        assert all(f["resting"] == "0" and 1 <= int(f["n_contacts"]) <= 3 for f in frames)
        assert all(f[f"x{int(f['n_contacts'])}_px"] != "" for f in frames)
    for k, frames in runs:
        if k == "none":
            assert all(float(f["intensity_mm"]) == 0.0 and f["n_contacts"] == "0" for f in frames)
