"""CPU of the contact step on a one-finger window: what looking for a finger the maxima missed
beside one contact costs (docs/performance.md, "Pipeline stages"; docs/method.md, "Contacts").

    python3 benchmarks/bench_one_contact.py [--calls 2000]

A Gaussian finger (12 px sigma, 6.7 px deep, off the centre) on the simulated 4 mm grid, one
contact; ``detect_contacts`` is called ``--calls`` times after 200 warm-up calls, each hearing the
maxima the call before held as a press's windows do (``held``), and each call's
CPU time of the calling thread (``time.thread_time_ns``, which other jobs on a shared machine do
not inflate) is kept: p50 and p90 in us. Run it beside a checkout of the code before a change
(``PYTHONPATH``) to compare.
"""

from __future__ import annotations

import time

import numpy as np
import typer

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.contacts import detect_contacts
from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours
from neurotouch_hid.views.console import command_app

app = command_app()


@app.command()
def main(calls: int = typer.Option(2000, "--calls", min=1)) -> None:
    sensor = SensorGeometry()
    k = np.arange(-8, 9) * 10.0
    grid = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(sensor.gel_center_px)
    rest = grid[sensor.inside_gel(grid, margin_px=-3.0)]
    centre = np.asarray(sensor.gel_center_px) + [10.0, -5.0]
    current = rest + np.exp(-np.sum((rest - centre) ** 2, axis=1) / 288.0)[:, None] * [6.0, -3.0]
    neighbours = rest_neighbours(rest, 10.0)
    found = detect_contacts(rest, current, neighbours=neighbours, long_before=False)
    assert found.count == 1
    for _ in range(200):
        found = detect_contacts(rest, current, neighbours=neighbours, long_before=False, held=found.held)
    times = []
    for _ in range(calls):
        start = time.thread_time_ns()
        found = detect_contacts(rest, current, neighbours=neighbours, long_before=False, held=found.held)
        times.append(time.thread_time_ns() - start)
    p50, p90 = np.percentile(times, [50, 90]) / 1e3
    print(f"one-finger window: detect_contacts CPU p50 {p50:.0f} us, p90 {p90:.0f} us ({calls} calls)")


if __name__ == "__main__":
    app()
