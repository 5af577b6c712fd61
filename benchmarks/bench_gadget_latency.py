"""From a window's decision to the host's evdev event, through the USB gadget (docs/performance.md,
"USB gadget latency").

The run's subscriber (``TargetOutputs`` over the ``hid`` gadget's targets, as ``run --output usb``
opens them) is handed a new state, as the runtime hands it each window's; the clock starts there.
It stops at the timestamp the kernel gives the host side's evdev event for that state (the
gadget's report taken by the host controller, usbhid, hid-input, evdev; the event node's clock set
to CLOCK_MONOTONIC, ``EVIOCSCLOCKID``, the clock ``time.monotonic`` reads). The left stick goes to
a new position every ``--every-ms`` (a window's cadence), ``--samples`` times; printed: p50, p99
and the largest (ms).

Needs root and a kernel with ``dummy_hcd`` (a UDC whose host side is the same kernel) and
``libcomposite``, ``usb_f_hid``, ``usbhid``, ``hid-generic``: the test kernel (tests/kernel/vm.py;
``check_usb_latency`` in tests/kernel/checks_gadget.py runs :func:`measure` there), or a machine
where ``modprobe dummy_hcd`` works. The gadget it makes is removed at the end.

Run: ``sudo python3 benchmarks/bench_gadget_latency.py [--samples 200] [--every-ms 10]``.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import select
import struct
import subprocess
import time

#: ``EVIOCSCLOCKID``: _IOW('E', 0xa0, int), linux/input.h.
EVIOCSCLOCKID = 0x400445A0
CLOCK_MONOTONIC = 1
MODULES = ("dummy_hcd", "libcomposite", "usb_f_hid", "usbhid", "hid-generic")


def _joystick_node(ids: tuple[int, int], timeout_s: float) -> str:
    from evdev import InputDevice, ecodes, list_devices

    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for path in list_devices():
            try:
                dev = InputDevice(path)
                axes = [c for c, _ in dev.capabilities().get(ecodes.EV_ABS, [])]
                if (dev.info.vendor, dev.info.product) == ids and ecodes.ABS_X in axes:
                    return path
            except OSError:
                continue
        time.sleep(0.05)
    raise RuntimeError(f"no host-side joystick {ids[0]:04x}:{ids[1]:04x} within {timeout_s} s")


def measure(samples: int = 200, every_ms: float = 10.0) -> dict:
    """Latencies (ms) of ``samples`` stick moves, ``every_ms`` apart: ``{"p50_ms", "p99_ms",
    "max_ms", "samples", "lost"}`` (``lost``: moves whose event did not come within 1 s)."""
    import numpy as np
    from evdev import InputDevice, ecodes

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.gadget import UsbGadget, configfs
    from neurotouch_hid.targets.protocols import PROTOCOLS

    for module in MODULES:
        subprocess.run(["modprobe", module], check=False, capture_output=True)
    configfs.mount_configfs()
    configfs.remove()
    latencies, lost = [], 0
    with UsbGadget("hid", load_profile("default")) as gadget, TargetOutputs(gadget.targets) as outputs:
        hid = PROTOCOLS["hid"]
        device = InputDevice(_joystick_node((hid.vendor, hid.product), 60.0))
        fcntl.ioctl(device.fd, EVIOCSCLOCKID, struct.pack("i", CLOCK_MONOTONIC))
        state = ControllerState.neutral()
        for i in range(samples):
            x = (1000 + 97 * i) * (1 if i % 2 else -1)  # a new value each time, both sides
            state.axes["ABS_X"] = x
            start = time.monotonic()
            outputs.write(state)
            seen = None
            while seen is None and time.monotonic() - start < 1.0:
                if not select.select([device.fd], [], [], 1.0)[0]:
                    break
                for event in device.read():
                    if event.type == ecodes.EV_ABS and event.code == ecodes.ABS_X and event.value == x:
                        seen = event.timestamp()
            if seen is None:
                lost += 1
            else:
                latencies.append((seen - start) * 1000)
            time.sleep(max(0.0, every_ms / 1000 - (time.monotonic() - start)))
        device.close()
    got = np.array(latencies)
    return {
        "samples": len(latencies),
        "lost": lost,
        "p50_ms": round(float(np.percentile(got, 50)), 2) if len(got) else None,
        "p99_ms": round(float(np.percentile(got, 99)), 2) if len(got) else None,
        "max_ms": round(float(got.max()), 2) if len(got) else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=200, help="stick moves measured")
    parser.add_argument("--every-ms", type=float, default=10.0, help="time between moves (ms)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args()
    result = measure(args.samples, args.every_ms)
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"decision -> host evdev event over the USB gadget: p50 {result['p50_ms']} ms, "
            f"p99 {result['p99_ms']} ms, max {result['max_ms']} ms ({result['samples']} moves, {result['lost']} lost)"
        )


if __name__ == "__main__":
    main()
