"""The whole pipeline on a simulated dataset (paper, section "Methodology"): predictions JSON
lines, the ``track`` and ``view`` commands, a fit reused where no marker moved, and the kernels it
compiles before a gesture."""

from __future__ import annotations

import json

import numpy as np
import pipeline_helpers
import pytest
from helpers import run_cli
from pipeline_helpers import SENSOR, events_at

from neurotouch_hid.core.dataset import read_predictions, write_predictions
from neurotouch_hid.core.errors import DatasetError, NeurotouchError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import Frame

rest_image = pipeline_helpers.rest_image  # a shared fixture, found by pytest under this name


# --- predictions JSON lines --------------------------------------------------------------------
def test_predictions_round_trip(tmp_path):
    estimates = [
        GestureEstimate(t_us=10000),
        GestureEstimate(
            t_us=20000,
            gesture=GestureType.TWIST_CW,
            resting=False,
            intensity_mm=2.5,
            contacts_px=np.array([[150.0, 120.0], [190.0, 125.0]]),
            contacts_mm=np.array([[-9.2, 4.0], [6.8, 2.0]]),
            rotation_rad=-0.2,
            scale=1.01,
        ),
    ]
    path = tmp_path / "pred.jsonl"
    assert write_predictions(path, estimates) == 2
    lines = path.read_text().splitlines()
    assert json.loads(lines[1])["contacts_mm"] == [[-9.2, 4.0], [6.8, 2.0]]
    back = read_predictions(path)
    assert [(e.t_us, e.gesture, e.resting, e.n_contacts) for e in back] == [
        (10000, GestureType.NONE, True, 0),
        (20000, GestureType.TWIST_CW, False, 2),
    ]
    assert back[1].rotation_rad == pytest.approx(-0.2)


@pytest.mark.parametrize(
    "line, message",
    [
        ("{not json", "pred.jsonl:2: not a JSON object"),
        ('{"t_us": 5, "gesture": "none", "resting": true}', "pred.jsonl:2: missing field(s) intensity_mm"),
        ('{"t_us": 5, "gesture": "wave", "resting": true, "intensity_mm": 0}', "pred.jsonl:2: bad value"),
        ('{"t_us": 1, "gesture": "none", "resting": true, "intensity_mm": 0}', "pred.jsonl:2: t_us 1 goes back"),
    ],
)
def test_bad_prediction_lines_name_file_and_line(tmp_path, line, message):
    path = tmp_path / "pred.jsonl"
    path.write_text('{"t_us": 2, "gesture": "none", "resting": true, "intensity_mm": 0}\n' + line + "\n")
    with pytest.raises(DatasetError) as err:
        read_predictions(path)
    assert message in str(err.value)


# --- end to end on a simulated recording ------------------------------------------------------
@pytest.fixture(scope="module")
def push_dataset(sim_push_recording):
    """A quick simulated push sequence (tests/conftest.py): AEDAT4 + labels + true markers."""
    return sim_push_recording


@pytest.fixture(scope="module")
def push_tracked(push_dataset, tmp_path_factory):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.pipeline.track import track_recording

    out = tmp_path_factory.mktemp("track")
    summary = track_recording(
        push_dataset, out / "pred.jsonl", find_sensor_file(push_dataset), markers_out=out / "m.npz"
    )
    return summary, read_predictions(out / "pred.jsonl"), np.load(out / "m.npz")


def test_track_finds_the_push_on_most_windows(push_dataset, push_tracked):
    from neurotouch_hid.core.dataset import read_labels

    summary, predictions, _ = push_tracked
    labels = read_labels(push_dataset.with_name(push_dataset.name.replace(".aedat4", ".labels.csv")))
    times = np.array([row.t_us for row in labels])
    assert summary.windows == len(predictions) > 100
    assert np.all(np.diff([p.t_us for p in predictions]) == 10_000)
    pushed, rested = [], []
    for p in predictions:
        i = np.searchsorted(times, p.t_us, side="right") - 1
        if i < 0:
            continue
        row = labels[i]
        if row.gesture is GestureType.PUSH and row.intensity_mm > 2.0:
            pushed.append(p.gesture is GestureType.PUSH and p.n_contacts >= 1)
        elif row.resting:
            rested.append(p.gesture is GestureType.NONE)
    assert len(pushed) > 30 and np.mean(pushed) >= 0.8
    assert len(rested) > 30 and np.mean(rested) >= 0.9


def test_track_markers_npz_follow_the_true_markers(push_dataset, push_tracked):
    _, predictions, markers = push_tracked
    truth = np.load(push_dataset.with_name(push_dataset.name.replace(".aedat4", ".markers.npz")))
    assert markers["t_us"].dtype == np.int64 and markers["positions_px"].dtype == np.float32
    np.testing.assert_array_equal(markers["t_us"], [p.t_us for p in predictions])
    n = len(markers["rest_px"])
    assert markers["positions_px"].shape == (len(predictions), n, 2)
    # every detected rest marker is a true marker (within 0.5 px)
    d = np.linalg.norm(markers["rest_px"][:, None] - truth["rest_px"][None], axis=2)
    assert d.min(axis=1).max() < 0.5
    # tracked positions stay near the true ones (nearest true marker at the same time)
    k = len(predictions) // 2
    j = int(np.argmin(np.abs(truth["t_us"] - markers["t_us"][k])))
    tracked = markers["positions_px"][k]
    tracked = tracked[np.isfinite(tracked).all(axis=1)]
    err = np.linalg.norm(tracked[:, None] - truth["positions_px"][j][None], axis=2).min(axis=1)
    assert np.median(err) < 1.0


def test_the_answered_intensity_leads_its_change_within_a_gesture_and_nothing_else(push_dataset):
    """docs/method.md, "Intensity lead": each window's intensity goes ``intensity_lead_us`` ahead along its
    change since the window before when that one had a gesture; types, contacts and the first window of
    each gesture are those of the pipeline without a lead."""
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.sources.recording import RecordingReader

    sensor = find_sensor_file(push_dataset)
    runs = {}
    for lead_us in (0, 3000):
        with RecordingReader(push_dataset) as reader:
            config = PipelineConfig(gesture={"intensity_lead_us": lead_us})
            runs[lead_us] = list(GesturePipeline(sensor, config).run(reader.stream()))
    plain, led = runs[0], runs[3000]
    assert [(p.t_us, p.gesture, p.n_contacts) for p in plain] == [(p.t_us, p.gesture, p.n_contacts) for p in led]
    rising = falling = 0
    for before, now, answered in zip(plain, plain[1:], led[1:]):
        if before.intensity_mm > 0 and now.intensity_mm > 0:  # two windows of one gesture
            change = now.intensity_mm - before.intensity_mm
            assert answered.intensity_mm == pytest.approx(max(0.0, now.intensity_mm + change * 0.3), abs=1e-9)
            rising += change > 0.05
            falling += change < -0.05
        else:
            assert answered.intensity_mm == now.intensity_mm
    assert rising > 3 and falling > 3  # the push's attack and release were both led
    with pytest.raises(ValueError, match="intensity_lead_us"):
        PipelineConfig(gesture={"intensity_lead_us": -1})
    with pytest.raises(ValueError, match="intensity_lead_us"):
        PipelineConfig(gesture={"intensity_lead_us": 60_000})


class _AlwaysFits(GesturePipeline):
    """The pipeline computing contacts and gesture afresh for every window (no reuse)."""

    fits = 0

    def _contacts_and_gesture(self, rest_px, current, valid):
        self.fits += 1
        return self._fit(rest_px, current, valid)


def test_windows_whose_markers_did_not_move_reuse_the_fit_with_identical_estimates(push_dataset):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.sources.recording import RecordingReader

    sensor = find_sensor_file(push_dataset)
    with RecordingReader(push_dataset) as reader:
        items = list(reader.stream(batch_us=1000))
    fitted = []
    reusing = GesturePipeline(sensor)
    real_fit = reusing._fit

    def counting_fit(*args):
        fitted.append(1)
        return real_fit(*args)

    reusing._fit = counting_fit
    fresh = _AlwaysFits(sensor)
    a, b = list(reusing.run(items)), list(fresh.run(items))
    assert [json.dumps(e.to_json_dict()) for e in a] == [json.dumps(e.to_json_dict()) for e in b]
    assert fresh.fits > 100  # moving windows
    assert 0 < len(fitted) < fresh.fits  # some windows had the same markers as the one before


def test_track_on_a_street_recording_says_no_gel_and_exits_2(any_street, tmp_path):
    done = run_cli("track", str(any_street.path), "--out", str(tmp_path / "p.jsonl"))
    assert done.returncode == 2
    assert "no gel found" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "p.jsonl").exists()


def test_track_command_writes_predictions_and_markers(push_dataset, push_tracked, tmp_path):
    done = run_cli(
        "track",
        str(push_dataset),
        "--out",
        str(tmp_path / "p.jsonl"),
        "--window-us",
        "5000",
        "--markers",
        str(tmp_path / "m.npz"),
    )
    assert done.returncode == 0, done.stderr
    predictions = read_predictions(tmp_path / "p.jsonl")
    assert np.all(np.diff([p.t_us for p in predictions]) == 5000)
    assert abs(len(predictions) - 2 * push_tracked[0].windows) <= 2  # twice the 10 ms windows
    assert len(np.load(tmp_path / "m.npz")["t_us"]) == len(predictions)
    assert "x real time" in done.stdout


def test_track_refuses_markers_and_predictions_under_one_name_before_it_writes(push_dataset, tmp_path):
    """Both were written to the one file: the predictions first, then the markers were refused as
    "the same file as the input", and the file held the predictions; an earlier file there was lost."""
    from neurotouch_hid.core.atomic import OutputError
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.pipeline.track import track_recording

    out = tmp_path / "both.npz"
    out.write_bytes(b"earlier markers")
    done = run_cli("track", str(push_dataset), "--out", str(out), "--markers", str(tmp_path / "." / "both.npz"))
    assert done.returncode == 2
    assert "the markers file is also the predictions file; give each its own name" in done.stderr, done.stderr
    assert out.read_bytes() == b"earlier markers"
    with pytest.raises(OutputError, match="the markers file is also the predictions file"):
        track_recording(
            push_dataset, tmp_path / "new.jsonl", find_sensor_file(push_dataset), markers_out=tmp_path / "new.jsonl"
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["both.npz"]


@pytest.mark.parametrize("suffix, scale", [(".png", 2), (".gif", 1)])
def test_view_writes_a_picture_of_the_right_size(push_dataset, tmp_path, suffix, scale):
    import imageio.v3 as iio

    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.views.pictures import render_view

    sensor = find_sensor_file(push_dataset)
    out = tmp_path / f"view{suffix}"
    drawn = render_view(push_dataset, out, sensor, scale=scale)
    assert drawn > 10 and out.stat().st_size > 1000
    pictures = iio.imread(out, index=None) if suffix == ".gif" else iio.imread(out)[None]
    assert pictures.shape[1:3] == (scale * sensor.height, scale * sensor.width)
    assert len(pictures) == (drawn if suffix == ".gif" else 1)
    assert pictures[..., :3].std() > 5  # not a blank picture


def test_a_gif_longer_than_its_bound_is_refused_and_what_was_there_is_kept(push_dataset, tmp_path, monkeypatch):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.views import pictures as view

    sensor = find_sensor_file(push_dataset)
    out = tmp_path / "view.gif"
    out.write_bytes(b"an earlier view")
    monkeypatch.setattr(view, "MAX_GIF_PICTURES", 5)
    with pytest.raises(NeurotouchError, match=r"more than 5 \(0.2 s at 25 pictures a second\).*write a \.mp4"):
        view.render_view(push_dataset, out, sensor, scale=1)
    assert out.read_bytes() == b"an earlier view"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.gif"]


def _numba_signatures() -> dict[str, int]:
    """Compiled signatures per numba function of the pipeline's modules."""
    import numba

    from neurotouch_hid.pipeline import contacts, contacts_held, gesture, learned, noise, resting, tracker

    return {
        f"{m.__name__}.{name}": len(f.signatures)
        for m in (contacts, contacts_held, gesture, learned, noise, resting, tracker)
        for name, f in vars(m).items()
        if isinstance(f, numba.core.registry.CPUDispatcher)
    }


def test_compile_kernels_leaves_nothing_to_compile_on_real_gestures(rest_image):
    """A run compiles while it starts, not mid-gesture (where it would drop events): after
    compile_kernels, a push, a wide flat top, a lone mistracked marker, a pinch and a three-finger
    twist compile nothing."""
    pipeline = GesturePipeline(SENSOR)
    pipeline.compile_kernels()
    compiled = _numba_signatures()
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    for width_px, peak_px in ((8.0, 3.0), (30.0, 4.0), (12.0, 5.0)):
        w = np.exp(-np.sum((rest - c) ** 2, axis=1) / (2 * width_px**2))
        moved = rest + np.minimum(1.0, 1.5 * w)[:, None] * [peak_px, 1.0]
        moved[7] += (6.0, 0.0)
        pipeline.tracker.reset(moved)
        pipeline.process(events_at(15000 * int(peak_px)))
    sides = [np.exp(-np.sum((rest - c - (dx, 0.0)) ** 2, axis=1) / (2 * 10.0**2))[:, None] for dx in (-25.0, 25.0)]
    pipeline.tracker.reset(rest + (sides[0] - sides[1]) * [5.0, 1.0])  # a pinch: the bump fit of its centres
    pipeline.process(events_at(90_000))
    assert pipeline._last_fit[4].count == 2
    twist = rest.copy()
    for angle in np.radians([30.0, 150.0, 270.0]):  # three fingers: the fit of their centres
        finger = np.exp(-np.sum((rest - c - 40.0 * np.array([np.cos(angle), np.sin(angle)])) ** 2, axis=1) / 242.0)
        twist += finger[:, None] * 4.0 * np.array([-np.sin(angle), np.cos(angle)])
    pipeline.tracker.reset(twist)
    pipeline.process(events_at(95_000))
    assert pipeline._last_fit[4].count == 3
    pipeline.process(Frame(100_000, rest_image))  # the resting detector's kernels
    assert _numba_signatures() == compiled


def test_the_window_checks_before_a_fit_match_numpy():
    from neurotouch_hid.pipeline.pipeline import _largest_move_sq, _unchanged

    rng = np.random.default_rng(9)
    rest = rng.uniform(50.0, 300.0, size=(177, 2))
    for trial in range(20):
        current = rest + rng.normal(scale=[0.01, 0.3, 3.0, 30.0][trial % 4], size=rest.shape)
        valid = rng.random(177) > [0.0, 0.2, 0.9, 1.0][trial % 4]
        if trial % 5 == 4:
            current[rng.integers(177)] = np.nan
        d = current[valid] - rest[valid]
        moved_sq = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
        largest = _largest_move_sq(current, valid, rest)
        if not valid.any():
            assert largest == -1.0
        elif np.isnan(moved_sq).any():
            assert np.isnan(largest)
        else:
            assert largest == moved_sq.max()
        same = current.copy()
        assert _unchanged(same, current, valid.copy(), valid) == (not np.isnan(current).any())
        same[trial % 177, trial % 2] += 1e-9
        assert not _unchanged(same, current, valid, valid)
        flipped = valid.copy()
        flipped[0] = not flipped[0]
        assert not _unchanged(current.copy(), current, flipped, valid)  # a marker lost or found
