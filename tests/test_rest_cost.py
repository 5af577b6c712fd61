"""A resting gel costs nothing but noticing the next touch: while the pipeline's verdict is
"resting", no window runs the contact search or the gesture fit, and a touch is noticed and
reported within one window of a pipeline that never skips them."""

from __future__ import annotations

import copy

import pytest

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline import tracker as tracker_module
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.pipeline.tracker import BlobTracker
from neurotouch_hid.sources.simulator import SimulatedSource


@pytest.fixture(scope="module")
def rest_push_rest():
    """4 s of the simulated gel, seed 0: rest, a push, its release, rest (items, 1 ms batches)."""
    sim = SimulatedSource(seed=0, gestures=["push"])
    return sim.sensor, list(sim.stream(4.0, batch_us=1000))


def replay(sensor, items, *, skip_at_rest: bool):
    """Every window's estimate and the window ends at which the contact search ran."""
    pipeline = GesturePipeline(sensor)
    searched: list[int] = []
    search = pipeline._contacts_and_gesture
    closing: list[int] = []

    def counted(*args):
        searched.append(closing[-1])
        return search(*args)

    pipeline._contacts_and_gesture = counted
    pipeline.on_window = lambda e: None
    estimate = pipeline._estimate

    def estimate_at(t_us):
        closing.append(t_us)
        return estimate(t_us)

    pipeline._estimate = estimate_at
    pipeline.rests_compiled = False  # each window's estimate is watched: every one on the general path
    if not skip_at_rest:  # the event path always overrules the verdict: every window is searched
        pipeline._moving = lambda current, valid: True
    estimates = [e for item in items for e in pipeline.process(item)]
    return estimates, searched


def test_no_contact_search_while_resting_and_the_touch_is_seen_within_one_window(rest_push_rest):
    sensor, items = rest_push_rest
    estimates, searched = replay(sensor, items, skip_at_rest=True)
    resting = {e.t_us for e in estimates if e.resting}
    assert len(resting) > 100  # the gel rests before and after the push
    assert not resting & set(searched)  # no window at rest ran the contact search
    pushed = [e.t_us for e in estimates if e.gesture is GestureType.PUSH]
    assert pushed, "the push is reported"

    full, _ = replay(sensor, items, skip_at_rest=False)
    window = GesturePipeline(sensor).config.window_us
    # the pipeline that searches every window sees the push first at `seen`; the one that skips
    # the resting windows notices it (a window not at rest) within one window of that, and
    # holds the push from at most one window after the other does
    seen = next(e.t_us for e in full if e.intensity_mm > 0)
    noticed = next(e.t_us for e in estimates if not e.resting and e.t_us >= seen - window)
    assert noticed <= seen + window
    assert held_push(estimates) <= held_push(full) + window


def held_push(estimates) -> int:
    """The first window of the first five in a row that report the push (us)."""
    kinds = [e.gesture for e in estimates]
    return next(e.t_us for k, e in enumerate(estimates) if kinds[k : k + 5] == [GestureType.PUSH] * 5)


class GeneralPath(GesturePipeline):
    """The pipeline with every window on the general path (a window estimate of its own)."""

    rests_compiled = False

    def _moving(self, current, valid):
        return super()._moving(current, valid)


def joined_per_window(items, window_us: int = 10_000) -> list:
    """The items as a paced run hands them on at rest: the event batches up to each window's end
    plus one batch joined into one, frames in between."""
    from neurotouch_hid.sources import Frame, join_events

    out, held = [], []
    for item in items:
        if isinstance(item, Frame):
            out += [join_events(held), item] if held else [item]
            held = []
            continue
        held.append(item)
        last = int(item["timestamp"][-1])
        if last // window_us != (last + 1000) // window_us:
            out.append(join_events(held))
            held = []
    return out + ([join_events(held)] if held else [])


@pytest.mark.parametrize("joined", [False, True], ids=["1 ms batches", "a window's batches joined"])
def test_the_compiled_resting_window_gives_the_general_paths_estimates_and_state(rest_push_rest, joined):
    sensor, items = rest_push_rest
    items = joined_per_window(items) if joined else items
    fast, general = GesturePipeline(sensor), GeneralPath(sensor)
    taken = []
    rest_window = fast._resting_events

    def counted(events):
        taken.append(rest_window(events))
        return taken[-1]

    fast._resting_events = counted
    ours = [e for item in items for e in fast.process(item)]
    theirs = [e for item in items for e in general.process(item)]
    assert sum(answer is not None for answer in taken) > 100  # the resting windows took the compiled path
    assert any(e.resting for e in ours) and any(e.gesture is GestureType.PUSH for e in ours)
    assert [repr(e) for e in ours] == [repr(e) for e in theirs]
    assert fast.tracker.positions_px.tobytes() == general.tracker.positions_px.tobytes()
    assert fast.tracker.counts == general.tracker.counts
    assert (fast.noise_filter.n_in, fast.noise_filter.n_out) == (general.noise_filter.n_in, general.noise_filter.n_out)


def test_the_reanchoring_at_rest_without_a_repaint_gives_the_full_resets_state(rest_push_rest):
    """At each APS frame at rest the tracker is re-anchored at the same rest positions; while its
    label images are those that reset painted, the reset is one compiled pass over the blobs'
    state. Each such reset leaves every array as the full reset does (state, covariance, times,
    rates, validity, cells, label images, counters), and the whole run's estimates are those of
    a pipeline that always resets in full."""
    sensor, items = rest_push_rest
    full_reset = BlobTracker.reset
    arrays = ("_state", "_cov", "_t_upd", "_t_seen", "_rate", "_valid", "_cell", "_label", "_neigh", "_counts")
    taken = []

    def checked(tracker, positions_px):
        before, painted = copy.deepcopy(tracker), tracker._painted
        full_reset(tracker, positions_px)
        if painted is None or tracker._painted is not painted:
            return  # the full reset ran
        taken.append(True)
        before._painted = None
        full_reset(before, positions_px)
        for name in arrays:
            assert getattr(tracker, name).tobytes() == getattr(before, name).tobytes(), name

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(BlobTracker, "reset", checked)
        pipeline = GesturePipeline(sensor)
        ours = [e for item in items for e in pipeline.process(item)]
    assert len(taken) > 30  # the frames at rest took the compiled pass
    assert pipeline._anchorings > len(taken)  # ... and not those after a frame correction or a repaint

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tracker_module, "_reset_if_painted", lambda *args: False)
        always_full = GesturePipeline(sensor)
        theirs = [e for item in items for e in always_full.process(item)]
    assert [repr(e) for e in ours] == [repr(e) for e in theirs]
    for name in arrays:
        assert getattr(pipeline.tracker, name).tobytes() == getattr(always_full.tracker, name).tobytes(), name


def test_a_resting_batchs_window_end_is_cut_where_numpys_searchsorted_cuts_it():
    """The resting window's cut (the first event at or after the window's end), written out
    instead of numba's searchsorted: the same index, ties and both ends included."""
    import numpy as np

    from neurotouch_hid.pipeline.rest_window import _first_at_or_after

    rng = np.random.default_rng(7)
    for n in (0, 1, 2, 5, 64, 1000):
        timestamps = np.sort(rng.integers(0, 50, n)).astype(np.int64)  # few values: many ties
        for t_us in (-1, 0, 1, 17, 25, 49, 50, 51):
            expected = int(np.searchsorted(timestamps, t_us))
            assert _first_at_or_after(timestamps, t_us) == expected
            assert _first_at_or_after.py_func(timestamps, t_us) == expected


def test_a_subclass_that_overrides_the_window_estimate_says_which_path_its_resting_windows_take():
    """A pipeline whose motion override or window estimate is its own does not silently take the
    compiled path at rest (which stands for the base class's): it must set ``rests_compiled``."""
    with pytest.raises(TypeError, match="overrides _moving: set rests_compiled"):

        class Silent(GesturePipeline):
            def _moving(self, current, valid):
                return True

    class Said(GesturePipeline):
        rests_compiled = False

        def _moving(self, current, valid):
            return True

    assert GesturePipeline.rests_compiled and not Said.rests_compiled
