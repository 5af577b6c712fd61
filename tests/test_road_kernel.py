"""The one output path in a REAL Linux kernel (Debian's, booted under qemu once per session by
tests/kernel/vm.py; the guest checks are tests/kernel/checks_road.py): a SIGTERM before the run
starts is a clean stop on every device output, the merged devices are grabbed and hidden before
the gel's device appears (a first run, its pipeline still compiling), and a profile's copilot
merges into the UHID and USB outputs, the USB host's rumble reaching the helper's pad. Skips,
with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


@pytest.fixture(scope="module")
def early(guest):
    return passed(guest, "checks_road.check_sigterm_before_the_run_and_merged_first")


@pytest.fixture(scope="module")
def merged(guest):
    return passed(guest, "checks_road.check_copilot_merges_into_hid_and_usb_and_gets_the_hosts_rumble")


@pytest.mark.parametrize("output", ["gamepad", "hid", "usb"])
def test_sigterm_before_the_run_is_a_clean_stop_with_the_merged_pad_hidden_before_the_device(early, output):
    """A first run (an empty numba cache): the helper's pad is grabbed (the check's own EVIOCGRAB
    fails) when the gel's device appears, while the pipeline compiles; a SIGTERM during the
    compile is a clean stop."""
    from neurotouch_hid.service.warmup import COMPILING

    done = early[output]
    assert done["said"][-1] == "stopped (SIGTERM) before the run started: every output released"
    assert done["grab_then"] == "EBUSY" and done["appeared_s"] <= done["compiling_s"]
    assert any(line.startswith(COMPILING) for line in done["said"])


def test_a_press_on_the_merged_pad_reaches_the_uhid_joystick(merged):
    assert merged["hid"]["said"]


def test_the_usb_hosts_rumble_reaches_the_merged_pad(merged):
    assert merged["xinput"]["helper_plays"] and merged["xinput"]["helper_uploads"]
