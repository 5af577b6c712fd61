"""An emulated DAVIS-346 on USB: replays an AEDAT4 recording as the camera would send it.

Usage (as root, in a kernel with dummy_hcd, libcomposite and usb_f_fs, e.g. the test kernel that
tests/kernel/vm.py boots)::

    python3 tests/kernel/davis_gadget.py RECORDING.aedat4 [--loop] [--from-s S] [--to-s S]
        [--frame-every N] [--gesture FROM:TO [--hold FROM:TO] [--gesture-slow N]]
        [--serial 00000001] [--verbose]

It loads dummy_hcd, libcomposite and usb_f_fs, mounts configfs, and makes a USB device appear on
the dummy host controller with the ids and descriptors of an iniVation DAVIS FX3 board
(152a:841a), written in Python on top of FunctionFS (the ``functionfs`` package). Any program
that opens a DAVIS through libusb -- dv-processing's ``dv_processing.io.camera``, libcaer, DV --
then finds a DAVIS-346 on that bus. It prints ``READY bus B device D`` on stdout once the device
is enumerated.

* **Control requests.** The host configures a DAVIS through two vendor requests (device
  recipient), both read from libcaer's source (src/usb_utils.h): 0xBF "FPGA config", wValue = module
  address, wIndex = parameter address, 4 data bytes = the 32-bit value, big-endian (OUT: write,
  IN: read); 0xC2 "FPGA config multiple", wValue = count, data = count x 6 bytes (module u8,
  parameter u8, value u32 big-endian). :class:`Registers` keeps every value written and answers
  reads with it; the read-only ones (logic version, chip id, clocks, sizes, orientation, which
  filters exist) hold what a DAVIS-346 reports (:data:`READ_ONLY`).
* **Data.** Bulk IN endpoint 0x82 carries 16-bit little-endian words (libcaer's
  ``davisCommonEventTranslator``): ``1ttt tttt tttt tttt`` timestamp (us, 15 bits, within the
  current wrap); code 7 timestamp wrap (+ 2^15 us x data); code 1 row (y) address; code 2/3 column
  (x) address with polarity OFF/ON, which completes an event at the current timestamp; code 0
  special events (1 timestamp reset, 9 rolling-shutter frame start, 14/15 exposure start/end,
  11/12 reset/signal column start, 13 column end, 10 frame end); code 4 an APS ADC sample (12
  bits); code 5 misc-8 data (sub-codes 1/2: the frame's ROI, high and low byte).
* **Pacing.** Events and frames leave at the recording's own pace (real time, in slices of about
  1 ms): a recording of T seconds takes T seconds. As on the FX3, data that does not fill a
  transfer waits at most the USB early packet delay the host wrote (module 9, parameter 1, in
  cycles of the 80 MHz USB clock; libcaer's 1 ms until then), then goes as one short transfer.
  The stream starts when the host sets USB "run" (module 9, parameter 0); DVS events flow while DVS
  "run" (1/3) is set, APS frames while APS "run" (2/4) is set. The recording starts over each
  time the host starts the stream, and with ``--loop`` it repeats (timestamps keep increasing).
* **Frames.** An APS frame of the recording (uint8 grey levels g) is sent as a rolling-shutter
  readout of 346 columns x 260 rows: reset samples R = 1023 for every pixel, then signal samples
  R - (4 g + 2); the driver's correlated double sampling gives (4 g + 2) << 6 on 16 bits, i.e.
  exactly g again on 8 bits. The samples stay within 10 bits: libcaer reads 12 bits of a sample
  word, but dv-processing 2.0.4 keeps only 10 (seen: a reset level of 1100 made every pixel white,
  1100 & 0x3FF being below the driver's 384 "over-exposed" threshold). Exposure start is the
  frame's own timestamp, exposure end that plus its exposure (or 4 ms when the recording says none).
* **Signals.** SIGTERM or SIGINT: unplug (the gadget is unbound from the controller) and exit.
  SIGUSR1: unplug and stay; SIGUSR2: plug in again (a new enumeration, like a re-plugged cable).
  SIGHUP: leave the replay now for ``--gesture FROM:TO`` (that part of the recording, once), then
  ``--hold FROM:TO`` again and again (the gesture held), until the host starts the stream again:
  a gesture on cue, e.g. once the program under test is ready for it. ``--gesture-slow N`` plays
  both N times slower (every time offset, exposures included, times N): the same motion, slower,
  for a host too slow to keep up with it in real time (the emulated test kernel).

Assumptions where libcaer's source does not say (each checked only against dv-processing's own
driver in the test kernel, never against a camera; tests/kernel/README.md has them all, with what
dv-processing 2.0.4 was seen to do beyond libcaer: the requests 0xB1 and 0xC6, its strict
timestamps, 10-bit samples; and why the interface has two unused bulk endpoints):

* Strings: manufacturer "iniVation", product "DAVIS346 (emulated)"; only the ids, the serial
  number and bcdDevice are read by the driver. bcdDevice's low byte is the firmware version
  libcaer compares (DAVIS_FX3_REQUIRED_FIRMWARE_VERSION); the logic version (SYSINFO 6/0) and
  patch level (6/7) are answered with the values its DAVIS_FX3_REQUIRED_* constants name.
* The FX3 board also has an interrupt IN endpoint 0x81 (libcaer's FX3 "debug" transfers); it is
  declared and never sends anything.
* Clocks (SYSINFO 6/3-6/6): logic 104 MHz, ADC 64 MHz, USB 80 MHz, deviation 1000 (= exact);
  they only convert exposure and frame-interval settings from us to cycles and back.
* The chip id answered is DAVIS346B (5); no IMU (IMU type 0), so no IMU samples are sent; no
  hardware statistics counters; the pixel, background-activity, ROI, skip and polarity filters are
  reported present but the replay does not apply them (the recording is sent as it is).
* The frame ROI is announced after each frame start (misc-8 sub-codes 1 then 2 for start column,
  start row, end column, end row), because the driver's frame-start handler resets its ROI
  parser; the whole 346x260 array is always read out.
* A timestamp reset request (MUX 0/2 set to 1) is answered at once with the special event 1, and
  device time restarts at 0 there.
* Wrap words are sent for every 2^15 us of device time, also when no event falls in it, as the
  FPGA does.

Not emulated: IMU samples, external input events, APS exposure control (frames keep the
recording's exposure and interval), the hardware filters, bias effects, USB 3 SuperSpeed
(dummy_hcd is a USB 2 high-speed controller here), and an FX3's buffer overruns.
"""

from __future__ import annotations

import argparse
import errno
import os
import select
import signal
import subprocess
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))  # the checkout's neurotouch_hid (recording reader)

VENDOR_ID, PRODUCT_ID = 0x152A, 0x841A
#: bcdDevice: the low byte is the firmware version the driver checks (libcaer src/davis.h:
#: DAVIS_FX3_REQUIRED_FIRMWARE_VERSION).
FIRMWARE_VERSION = 6
LOGIC_VERSION = 18
LOGIC_PATCH = 1
DATA_ENDPOINT = 0x82
DEBUG_ENDPOINT = 0x81
#: The kernel numbers a FunctionFS function's endpoints itself (usb_ep_autoconfig takes the first
#: free controller endpoint that fits, whatever address the descriptor asks for). dummy_hcd's IN
#: endpoints that can do bulk come in the order ep1, ep6, ep11, ep2, ...: the debug endpoint
#: takes ep1 (0x81), these two unused bulk endpoints take ep6 and ep11, and the data endpoint
#: then gets ep2, the 0x82 that libcaer's DAVIS driver hard-codes.
PLACEHOLDER_ENDPOINTS = (0x83, 0x84)
GADGET_NAME = "davis346_emulated"
CONFIGFS = Path("/sys/kernel/config")

VR_FPGA_CONFIG = 0xBF
VR_FPGA_CONFIG_MULTIPLE = 0xC2

# module addresses (libcaer include/libcaer/devices/davis.h)
MUX, DVS, APS, IMU, EXTINPUT, SYSINFO, USB = 0, 1, 2, 3, 4, 6, 9
WIDTH, HEIGHT = 346, 260

#: (module, parameter) -> value of the read-only registers the driver reads on open.
READ_ONLY = {
    (SYSINFO, 0): LOGIC_VERSION,
    (SYSINFO, 1): 5,
    (SYSINFO, 2): 1,  # logic version, DAVIS346B, master
    (SYSINFO, 3): 104,
    (SYSINFO, 4): 64,
    (SYSINFO, 5): 80,
    (SYSINFO, 6): 1000,  # clocks (MHz), deviation
    (SYSINFO, 7): LOGIC_PATCH,
    (DVS, 0): WIDTH,
    (DVS, 1): HEIGHT,
    (DVS, 2): 0,  # size, orientation
    (DVS, 10): 1,
    (DVS, 30): 1,
    (DVS, 40): 1,
    (DVS, 50): 1,
    (DVS, 60): 1,
    (DVS, 80): 0,  # filters, stats
    (APS, 0): WIDTH,
    (APS, 1): HEIGHT,
    (APS, 2): 0,
    (APS, 3): 0,
    (APS, 6): 1,  # size, orient., mono, GS
    (IMU, 0): 0,
    (IMU, 1): 0,  # no IMU
    (EXTINPUT, 10): 0,
    (MUX, 80): 0,  # no generator, no statistics
}

# data words (libcaer davisCommonEventTranslator)
TS_WRAP_US = 0x8000
W_TS, W_WRAP, W_Y, W_X_OFF, W_X_ON, W_ADC, W_MISC8 = 0x8000, 0x7000, 0x1000, 0x2000, 0x3000, 0x4000, 0x5000
SP_TS_RESET, SP_FRAME_START_RS, SP_FRAME_END = 1, 9, 10
SP_RESET_COL, SP_SIGNAL_COL, SP_COL_END, SP_EXPOSURE_START, SP_EXPOSURE_END = 11, 12, 13, 14, 15
#: ADC reset level of every pixel; signal = RESET_LEVEL - (4 g + 2) (module docstring, "Frames").
RESET_LEVEL = 1023
DEFAULT_EXPOSURE_US = 4000
#: Bytes per IN transfer and transfers in flight (the FX3 sends what the host asks for).
CHUNK_BYTES = 16384
MAX_IN_FLIGHT = 16
#: Pending data beyond this (bytes) is dropped, like an FX3 whose host does not read.
MAX_BACKLOG_BYTES = 4 << 20
#: USB module parameter 1, the early packet delay: data that does not fill a transfer waits at most
#: this long before it is sent as a short one. libcaer writes it in cycles of the USB clock (its
#: 125 us slices x 125 x USB_CLOCK_MHZ, src/davis.c ``davisFX3ConfigSet``); until the host writes
#: it, libcaer's default: 8 slices, 1 ms.
USB_EARLY_PACKET_DELAY = 1
USB_CLOCK_MHZ = READ_ONLY[(SYSINFO, 5)]
DEFAULT_EARLY_PACKET_DELAY_US = 1000
#: While a stream runs, the data endpoint's counts are logged this often (s).
STATS_EVERY_S = 1.0
#: FunctionFS's errors for a control transfer the host gave up on, or for a gadget unbound meanwhile
CANCELLED = (errno.EIDRM, errno.ESHUTDOWN)


def log(msg: str) -> None:
    print(f"davis_gadget: {time.monotonic():.3f} {msg}", file=sys.stderr, flush=True)


class Registers:
    """The FPGA's configuration registers as the host sees them through requests 0xBF/0xC2."""

    def __init__(self) -> None:
        self.values: dict[tuple[int, int], int] = dict(READ_ONLY)
        self.on_write = lambda module, param, value: None

    def read(self, module: int, param: int) -> int:
        return self.values.get((module, param), 0)

    def write(self, module: int, param: int, value: int) -> None:
        if (module, param) not in READ_ONLY:
            self.values[(module, param)] = value
        self.on_write(module, param, value)


class WordEncoder:
    """Turns events and frames (device time, us) into the DAVIS 16-bit word stream.

    Keeps the wire state between calls: the last timestamp sent, the wrap count and the last row.
    """

    def __init__(self) -> None:
        self.reset(0)

    def reset(self, t_us: int) -> None:
        self.last_t = -1
        self.wrap = t_us // TS_WRAP_US
        self.last_y = -1

    def _wrap_words(self, t: int) -> list[int]:
        """Wrap words that bring the wrap count up to device time ``t`` (12 bits of count each).

        A wrap sets the driver's current timestamp to the wrap's start; a timestamp word equal to
        it would then be a repeated timestamp, which dv-processing's parser rejects."""
        words = []
        wrap = t // TS_WRAP_US
        while wrap > self.wrap:
            step = min(wrap - self.wrap, 0xFFF)
            words.append(W_WRAP | step)
            self.wrap += step
            self.last_t = self.wrap * TS_WRAP_US
        return words

    def _time_words(self, t: int) -> list[int]:
        words = self._wrap_words(t)
        if t != self.last_t:
            words.append(W_TS | (t % TS_WRAP_US))
            self.last_t = t
        return words

    def idle(self, t: int) -> np.ndarray:
        """Wrap words up to device time ``t`` (no event or frame since)."""
        return np.asarray(self._wrap_words(t), np.uint16)

    def events(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Words for time-ordered events (int64 us, device time): [wrap] [timestamp] [row] column."""
        n = len(t)
        if n == 0:
            return np.zeros(0, np.uint16)
        wrap = t // TS_WRAP_US
        prev_wrap = np.concatenate(([self.wrap], wrap[:-1]))
        prev_t = np.concatenate(([self.last_t], t[:-1]))
        prev_y = np.concatenate(([self.last_y], y[:-1]))
        dwrap = wrap - prev_wrap
        big = np.flatnonzero(dwrap > 0xFFF)  # a silence of more than 134 s: several wrap words
        if len(big):
            k = int(big[0])
            head = self.events(t[:k], x[:k], y[:k], p[:k])
            wraps = np.asarray(self._wrap_words(int(t[k])), np.uint16)
            return np.concatenate([head, wraps, self.events(t[k:], x[k:], y[k:], p[k:])])
        slots = np.zeros((n, 4), np.uint16)
        mask = np.zeros((n, 4), bool)
        slots[:, 0] = W_WRAP | dwrap.astype(np.uint16)
        mask[:, 0] = dwrap > 0
        slots[:, 1] = W_TS | (t % TS_WRAP_US).astype(np.uint16)
        mask[:, 1] = np.where(dwrap > 0, t != wrap * TS_WRAP_US, t != prev_t)
        slots[:, 2] = W_Y | y.astype(np.uint16)
        mask[:, 2] = y != prev_y
        slots[:, 3] = np.where(p > 0, W_X_ON, W_X_OFF).astype(np.uint16) | x.astype(np.uint16)
        mask[:, 3] = True
        self.wrap, self.last_t, self.last_y = int(wrap[-1]), int(t[-1]), int(y[-1])
        return slots[mask]

    def frame_start(self, t: int) -> np.ndarray:
        """Frame start, its ROI (the whole array) and exposure start, at device time ``t``."""
        words = self._time_words(t) + [SP_FRAME_START_RS]
        for value in (0, 0, WIDTH - 1, HEIGHT - 1):  # start column, start row, end column, end row
            words += [W_MISC8 | 0x100 | (value >> 8), W_MISC8 | 0x200 | (value & 0xFF)]
        words.append(SP_EXPOSURE_START)
        return np.asarray(words, np.uint16)

    def frame_end(self, t: int, image: np.ndarray) -> np.ndarray:
        """Exposure end at device time ``t``, the readout of ``image`` (uint8 (260, 346)), frame end."""
        head = np.asarray(self._time_words(t) + [SP_EXPOSURE_END], np.uint16)
        reset = np.empty((WIDTH, HEIGHT + 2), np.uint16)
        reset[:, 0], reset[:, -1] = SP_RESET_COL, SP_COL_END
        reset[:, 1:-1] = W_ADC | RESET_LEVEL
        signal_ = np.empty((WIDTH, HEIGHT + 2), np.uint16)
        signal_[:, 0], signal_[:, -1] = SP_SIGNAL_COL, SP_COL_END
        signal_[:, 1:-1] = W_ADC | (RESET_LEVEL - (4 * image.T.astype(np.uint16) + 2))
        return np.concatenate([head, reset.ravel(), signal_.ravel(), np.asarray([SP_FRAME_END], np.uint16)])


class Replay:
    """The recording as a schedule: what to send up to a given time since the stream started."""

    def __init__(
        self,
        path: Path,
        loop: bool,
        frame_every: int = 1,
        from_s: float = 0.0,
        to_s: float | None = None,
        slow: float = 1.0,
    ) -> None:
        """The part of ``path`` from ``from_s`` to ``to_s`` (s after its first event or frame),
        every ``frame_every``-th APS frame, ``slow`` times slower than recorded (each time
        offset, exposures included, multiplied by ``slow``), repeated when ``loop``."""
        from neurotouch_hid.sources.recording import RecordingReader

        with RecordingReader(path, require_resolution=(WIDTH, HEIGHT)) as reader:
            events, frames = reader.read_all()
            exposures = self._exposures(path) if reader.has_frames else {}
        starts = [int(events["timestamp"][0])] if len(events) else []
        first = min(starts + [f.t_us for f in frames], default=0)
        lo = first + int(from_s * 1e6)
        hi = None if to_s is None else first + int(to_s * 1e6)
        events = events[(events["timestamp"] >= lo) & ((events["timestamp"] < hi) if hi is not None else True)]
        frames = [f for f in frames if f.t_us >= lo and (hi is None or f.t_us < hi)]
        if len(events) == 0 and not frames:
            raise SystemExit(f"{path}: no events and no frames to replay (between {from_s} s and {to_s} s)")
        self.t0 = lo
        self.t = ((events["timestamp"] - self.t0) * slow).astype(np.int64)
        self.x, self.y, self.p = events["x"], events["y"], events["polarity"]
        # frame marks: (time since start, 0 = exposure start / 1 = readout, frame index)
        marks = []
        for i, f in enumerate(frames):
            if i % frame_every:
                continue
            start = int((f.t_us - self.t0) * slow)
            marks += [(start, 0, i), (start + int(exposures.get(f.t_us, DEFAULT_EXPOSURE_US) * slow), 1, i)]
        self.marks = sorted(marks)
        self.images = [f.image for f in frames]
        last = max(([int(self.t[-1])] if len(self.t) else []) + [m[0] for m in self.marks[-1:]])
        self.period = last + 1000  # us; a loop starts 1 ms after the last item
        self.loop = loop
        self.duration_s = self.period / 1e6

    @staticmethod
    def _exposures(path: Path) -> dict[int, int]:
        """Frame timestamp -> exposure (us), as the recording stores it (0 when it does not)."""
        import dv_processing as dv

        out = {}
        rec = dv.io.MonoCameraRecording(str(path))
        while True:
            frame = rec.getNextFrame()
            if frame is None:
                break
            exposure = int(frame.exposure.total_seconds() * 1e6)
            if exposure > 0:
                out[int(frame.timestamp)] = exposure
        return out


class Stream:
    """The word stream of one start of the data (USB run): replay position and encoder state."""

    def __init__(self, replay: Replay, t_dev0: int) -> None:
        self.replay = replay
        self.t_dev0 = t_dev0  # device time at which the stream's t_rel = 0 is sent
        self.encoder = WordEncoder()
        self.encoder.reset(t_dev0)
        self.offset = 0  # t_rel (us) at which the current replay's t = 0 is sent
        self.lap = 0
        self.event_pos = 0
        self.mark_pos = 0
        self.done = False
        self.following: list[Replay] = []  # played in turn once the current one is done
        self.events_sent = 0  # DVS events and APS frames queued so far (the stats line says them)
        self.frames_sent = 0

    def cue(self, t_rel: int, replays: list[Replay]) -> None:
        """Leave the current replay at ``t_rel`` (us after the stream start; what is due before
        it has been sent) for ``replays[0]``, then each of the others in turn."""
        self._switch(t_rel, replays[0])
        self.following = list(replays[1:])

    def _switch(self, t_rel: int, replay: Replay) -> None:
        self.replay, self.offset = replay, t_rel
        self.lap = self.event_pos = self.mark_pos = 0
        self.done = False

    def until(self, t_rel: int, dvs: bool, aps: bool) -> list[np.ndarray]:
        """Words for everything due up to ``t_rel`` us after the stream start."""
        out: list[np.ndarray] = []
        while not self.done:
            r = self.replay
            base = self.offset + self.lap * r.period
            limit = t_rel - base
            end = int(np.searchsorted(r.t, limit, side="right"))
            while self.event_pos < end or (self.mark_pos < len(r.marks) and r.marks[self.mark_pos][0] <= limit):
                next_mark = r.marks[self.mark_pos][0] if self.mark_pos < len(r.marks) else None
                stop = end if next_mark is None else min(end, int(np.searchsorted(r.t, next_mark, side="right")))
                if stop > self.event_pos:
                    s = slice(self.event_pos, stop)
                    if dvs:
                        out.append(self.encoder.events(r.t[s] + base + self.t_dev0, r.x[s], r.y[s], r.p[s]))
                        self.events_sent += stop - self.event_pos
                    self.event_pos = stop
                    continue
                t_mark, kind, index = r.marks[self.mark_pos]
                self.mark_pos += 1
                if aps:
                    t_dev = t_mark + base + self.t_dev0
                    out.append(
                        self.encoder.frame_start(t_dev) if kind == 0 else self.encoder.frame_end(t_dev, r.images[index])
                    )
                    self.frames_sent += kind
            if limit < r.period:
                break
            if not r.loop:
                if self.following:
                    self._switch(base + r.period, self.following.pop(0))
                    continue
                self.done = True
                break
            self.lap += 1
            self.event_pos = self.mark_pos = 0
        out.append(self.encoder.idle(t_rel + self.t_dev0))
        return [w for w in out if len(w)]


def _make_function_class():
    import functionfs
    from functionfs import ch9

    class DavisFunction(functionfs.Function):
        """The camera's interface 0: vendor requests on ep0, data on 0x82, FX3 debug on 0x81."""

        def __init__(self, path: str, device: "DavisDevice") -> None:
            self.device = device
            fs_list, hs_list, ss_list = functionfs.getInterfaceInAllSpeeds(
                interface={"bInterfaceClass": ch9.USB_CLASS_VENDOR_SPEC, "iInterface": 1},
                endpoint_list=[
                    {
                        "endpoint": {
                            "bEndpointAddress": DEBUG_ENDPOINT,
                            "bmAttributes": ch9.USB_ENDPOINT_XFER_INT,
                            "bInterval": 1,
                        }
                    },
                    *(
                        {"endpoint": {"bEndpointAddress": address, "bmAttributes": ch9.USB_ENDPOINT_XFER_BULK}}
                        for address in PLACEHOLDER_ENDPOINTS
                    ),
                    {"endpoint": {"bEndpointAddress": DATA_ENDPOINT, "bmAttributes": ch9.USB_ENDPOINT_XFER_BULK}},
                ],
            )
            super().__init__(
                path,
                fs_list=fs_list,
                hs_list=hs_list,
                ss_list=ss_list,
                lang_dict={0x0409: ["DAVIS data"]},
                all_ctrl_recip=True,
                in_aio_blocks_max=MAX_IN_FLIGHT + 2,
            )

        def getEndpointClass(self, is_in, descriptor):
            device = self.device

            class DataEndpoint(functionfs.EndpointINFile):
                def onComplete(self, buffer_list, user_data, status):
                    device.in_flight -= 1
                    if status < 0 and status != -errno.ESHUTDOWN:
                        device.note(f"data transfer failed: {os.strerror(-status)}")
                    return False

            return DataEndpoint if is_in else functionfs.EndpointOUTFile

        def onEnable(self):
            super().onEnable()
            self.device.enabled()

        def onDisable(self):
            self.device.disabled("disable")

        def onUnbind(self):
            self.device.disabled("unbind")

        def onSetup(self, request_type, request, value, index, length):
            try:
                self._answer(request_type, request, value, index, length)
            except OSError as exc:
                # FunctionFS says EIDRM when the host gave up on this control transfer before it
                # was answered (a new SETUP came: libusb's timeout on a slow, emulated machine),
                # ESHUTDOWN when the gadget was unbound meanwhile; a real camera just takes the
                # next request
                if exc.errno not in CANCELLED:
                    raise
                self.device.note(f"control request 0x{request:02x} cancelled by the host ({exc.strerror})")

        def _answer(self, request_type, request, value, index, length):
            if request_type & ch9.USB_TYPE_MASK != ch9.USB_TYPE_VENDOR:
                return super().onSetup(request_type, request, value, index, length)
            if request_type & ch9.USB_DIR_IN:
                data = self.device.vendor_in(request, value, index, length)
                if data is None:
                    self.ep0.halt(request_type)
                else:
                    self.ep0.write(data)
            else:
                data = self.ep0.read(length) if length else b""
                if length == 0:
                    self.ep0.read(0)
                self.device.vendor_out(request, value, index, data)

    return DavisFunction


class DavisDevice:
    """Register file, stream state and the data endpoint's queue of the emulated camera."""

    def __init__(self, replay: Replay, verbose: bool, cued: list[Replay] | None = None) -> None:
        self.replay = replay
        self.cued = cued or []  # what SIGHUP plays: --gesture once, then --hold looped
        self.verbose = verbose
        self.registers = Registers()
        self.registers.on_write = self._on_write
        self.function = None
        self.in_flight = 0
        self.backlog: deque[memoryview] = deque()
        self.backlog_bytes = 0
        self.pending = bytearray()  # less than a transfer, held for the early packet delay
        self.pending_since = 0.0  # when its first byte was queued (time.monotonic())
        self.transfers = 0
        self.short_transfers = 0  # of them, sent before they were full (the early packet delay)
        self.dropped_bytes = 0
        self.clock0 = time.monotonic()  # device time 0 (timestamp reset)
        self.stream: Stream | None = None
        self.stream_wall0 = 0.0
        self.requests: dict[str, int] = {}
        self.sent_bytes = 0

    def note(self, msg: str) -> None:
        log(msg)

    def device_time(self) -> int:
        return int((time.monotonic() - self.clock0) * 1e6)

    # --- control requests ---------------------------------------------------------------------
    def _count(self, what: str) -> None:
        self.requests[what] = self.requests.get(what, 0) + 1

    def vendor_in(self, request: int, value: int, index: int, length: int) -> bytes | None:
        if request == VR_FPGA_CONFIG and length == 4:
            result = self.registers.read(value, index)
            self._count(f"read {value}/{index}")
            if self.verbose:
                log(f"read  module {value} param {index} -> {result}")
            return result.to_bytes(4, "big")
        self._count(f"in 0x{request:02x}")
        log(f"unknown IN request 0x{request:02x} value {value} index {index} length {length}: stalled")
        return None

    def vendor_out(self, request: int, value: int, index: int, data: bytes) -> None:
        if request == VR_FPGA_CONFIG and len(data) == 4:
            self.registers.write(value, index, int.from_bytes(data, "big"))
            return
        if request == VR_FPGA_CONFIG_MULTIPLE and len(data) == 6 * value:
            for k in range(value):
                chunk = data[6 * k : 6 * k + 6]
                self.registers.write(chunk[0], chunk[1], int.from_bytes(chunk[2:], "big"))
            return
        self._count(f"out 0x{request:02x}")
        log(f"unknown OUT request 0x{request:02x} value {value} index {index} data {data.hex()}: ignored")

    def _on_write(self, module: int, param: int, value: int) -> None:
        self._count(f"write {module}/{param}")
        if self.verbose:
            log(f"write module {module} param {param} = {value}")
        if (module, param) == (MUX, 2) and value:  # timestamp reset
            self.clock0 = time.monotonic()
            if self.stream is not None:  # what is due goes out before; device time restarts at 0
                self.pump(submit=False)
                self._flush(time.monotonic(), force=True)
                self.stream.t_dev0 = -int((self.clock0 - self.stream_wall0) * 1e6)
                self.stream.encoder.reset(0)
            self._queue(np.asarray([SP_TS_RESET], np.uint16))
            self._flush(time.monotonic(), force=True)  # the host waits for it (time synchronisation)
            # device time = (time.monotonic() - clock0) x 1e6 us: a guest check reads the events' age
            log(f"timestamp reset: device time 0 at monotonic {self.clock0:.6f} s")
        elif (module, param) == (USB, USB_EARLY_PACKET_DELAY):
            log(f"USB early packet delay {value / USB_CLOCK_MHZ:g} us")
        elif (module, param) == (USB, 0):
            if value and self.stream is None:
                self._start_stream()
            elif not value:
                self._stop_stream("USB run cleared")

    # --- streaming ----------------------------------------------------------------------------
    def _start_stream(self) -> None:
        self.stream_wall0 = time.monotonic()
        self.stream = Stream(self.replay, self.device_time())
        log(
            f"stream started ({self.replay.duration_s:.2f} s of recording"
            f"{f', looped every {self.replay.period} us' if self.replay.loop else ''})"
        )

    def play_cued(self) -> None:
        """SIGHUP: the stream leaves the replay now for the cued ones (--gesture, then --hold), until
        the host starts the stream again (which starts over from the first replay)."""
        if self.stream is None or not self.cued:
            log("SIGHUP: nothing cued (no --gesture) or no stream running; ignored")
            return
        self.stream.cue(int((time.monotonic() - self.stream_wall0) * 1e6), self.cued)
        log(f"SIGHUP: playing the cued gesture ({', '.join(f'{r.duration_s:.2f} s' for r in self.cued)})")

    def _stop_stream(self, why: str) -> None:
        if self.stream is not None:
            log(
                f"stream stopped: {why}; {self.sent_bytes} bytes sent in {self.transfers} transfers, "
                f"{self.dropped_bytes} dropped"
            )
        self.stream = None
        self.backlog.clear()
        self.backlog_bytes = 0
        self.pending.clear()
        if self.function is not None and self.in_flight:
            # what the host has not read yet must not reach its next session (an FX3 flushes too);
            # functionfs has no public call for this, its AIO context has
            try:
                self.function._in_aio_context.cancelAll()
            except OSError as exc:  # unbound meanwhile: the kernel ends them itself
                self.note(f"cannot cancel queued data ({exc})")

    def enabled(self) -> None:
        log("enabled by the host (configuration set)")

    def disabled(self, why: str) -> None:
        self._stop_stream(why)
        for key in [k for k in self.registers.values if k not in READ_ONLY]:
            del self.registers.values[key]

    def early_packet_delay_s(self) -> float:
        """How long data that does not fill a transfer is held (s): the host's USB early packet
        delay (:data:`USB_EARLY_PACKET_DELAY`), or libcaer's default before it writes one."""
        cycles = self.registers.read(USB, USB_EARLY_PACKET_DELAY)
        return (cycles / USB_CLOCK_MHZ if cycles else DEFAULT_EARLY_PACKET_DELAY_US) / 1e6

    def _queue(self, words: np.ndarray) -> None:
        """Words to send: every full transfer (CHUNK_BYTES) at once, the rest held (:meth:`_flush`)."""
        data = words.astype("<u2").tobytes()
        if self.backlog_bytes + len(self.pending) + len(data) > MAX_BACKLOG_BYTES:
            self.dropped_bytes += len(data)
            return
        if not self.pending:
            self.pending_since = time.monotonic()
        self.pending += data
        full = len(self.pending) - len(self.pending) % CHUNK_BYTES
        if full:
            self._to_backlog(self.pending[:full])
            del self.pending[:full]
            self.pending_since = time.monotonic()

    def _to_backlog(self, data: bytes | bytearray) -> None:
        view = memoryview(bytearray(data))
        for start in range(0, len(view), CHUNK_BYTES):
            self.backlog.append(view[start : start + CHUNK_BYTES])
        self.backlog_bytes += len(data)

    def _flush(self, now: float, force: bool = False) -> None:
        """The held data as a short transfer once it waited the early packet delay (or ``force``)."""
        if self.pending and (force or now - self.pending_since >= self.early_packet_delay_s()):
            self._to_backlog(self.pending)
            self.pending.clear()
            self.short_transfers += 1

    def stats(self) -> str:
        """The data endpoint's counts so far, as logged once a second while a stream runs (the
        guest checks read the transfers a second from them); the events and frames queued in this
        stream, and the bytes dropped because the host did not read them."""
        events, frames = (self.stream.events_sent, self.stream.frames_sent) if self.stream else (0, 0)
        return (
            f"sent {self.transfers} transfers ({self.short_transfers} short), {self.sent_bytes} bytes; "
            f"queued {events} events, {frames} frames; dropped {self.dropped_bytes} bytes"
        )

    def pump(self, submit: bool = True) -> None:
        """Queue what is due now; submit queued data while transfers are free."""
        stream = self.stream
        if stream is not None:
            regs = self.registers
            t_rel = int((time.monotonic() - self.stream_wall0) * 1e6)
            words = stream.until(t_rel, dvs=bool(regs.read(DVS, 3)), aps=bool(regs.read(APS, 4)))
            if words:
                self._queue(np.concatenate(words))
        self._flush(time.monotonic())
        if self.function is None or not submit:
            return
        endpoint = self.function.getEndpointByAddress(DATA_ENDPOINT)
        while self.backlog and self.in_flight < MAX_IN_FLIGHT:
            chunk = self.backlog.popleft()
            self.backlog_bytes -= len(chunk)
            try:
                endpoint.submit([chunk])
            except OSError as exc:
                self.note(f"cannot submit data ({exc}); dropped")
                continue
            self.in_flight += 1
            self.sent_bytes += len(chunk)
            self.transfers += 1


# --- the gadget in configfs --------------------------------------------------------------------
def process_events(function, device: "DavisDevice", attempts: int = 3) -> None:
    """FunctionFS's ep0 events and data completions (``function.processEvents()``), taking a
    cancelled control transfer in its stride.

    When the host gives up on a control transfer (libusb's timeout on the slow, emulated guest)
    while its SETUP event is still queued, FunctionFS fails the gadget's next ep0 *event read*
    with EIDRM once, clearing the cancelled state; the events behind it are still queued and the
    eventfd that announced them is already consumed, so they are read again at once. Raises
    OSError for anything else, or when the read keeps failing ``attempts`` times."""
    for attempt in range(attempts):
        try:
            function.processEvents()
            return
        except OSError as exc:
            if exc.errno not in CANCELLED or attempt == attempts - 1:
                raise
            device.note(f"ep0 events: a control transfer cancelled by the host ({exc.strerror}); reading on")


def load_modules() -> None:
    for module in ("dummy_hcd", "libcomposite", "usb_f_fs"):
        proc = subprocess.run(["modprobe", module], capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"modprobe {module} failed: {proc.stderr.strip()}")
    if not (CONFIGFS / "usb_gadget").exists():
        subprocess.run(["mount", "-t", "configfs", "none", str(CONFIGFS)], check=False)


def find_device(serial: str) -> Path | None:
    """The emulated camera in sysfs (host side), once enumerated."""
    for dev in Path("/sys/bus/usb/devices").iterdir():
        try:
            if (
                (dev / "idVendor").read_text().strip() == f"{VENDOR_ID:04x}"
                and (dev / "idProduct").read_text().strip() == f"{PRODUCT_ID:04x}"
                and (dev / "serial").read_text().strip() == serial
            ):
                return dev
        except OSError:
            continue
    return None


def _span(text: str) -> tuple[float, float]:
    """``FROM:TO`` (s) -> (from_s, to_s), for argparse."""
    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FROM:TO in seconds, e.g. 0.55:2.0, got {text!r}") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"expected 0 <= FROM < TO, got {text!r}")
    return lo, hi


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="AEDAT4 file (346x260 events, APS frames optional)")
    parser.add_argument("--loop", action="store_true", help="replay the recording again and again")
    parser.add_argument("--serial", default="00000001", help="USB serial number (8 characters)")
    parser.add_argument(
        "--from-s",
        type=float,
        default=0.0,
        metavar="S",
        help="replay from S seconds after the recording's first event or frame",
    )
    parser.add_argument(
        "--to-s",
        type=float,
        default=None,
        metavar="S",
        help="replay up to S seconds after the recording's first event or frame",
    )
    parser.add_argument(
        "--frame-every",
        type=int,
        default=1,
        metavar="N",
        help="send only every N-th APS frame (a slow, emulated host cannot read 9 MB/s)",
    )
    parser.add_argument(
        "--gesture-slow",
        type=float,
        default=1.0,
        metavar="N",
        help="play --gesture and --hold N times slower than recorded (an emulated host is slow)",
    )
    parser.add_argument(
        "--gesture",
        type=_span,
        default=None,
        metavar="FROM:TO",
        help="on SIGHUP, leave the replay for this part of the recording (s), played once",
    )
    parser.add_argument(
        "--hold",
        type=_span,
        default=None,
        metavar="FROM:TO",
        help="after --gesture, this part of the recording (s) again and again (a gesture held)",
    )
    parser.add_argument("--verbose", action="store_true", help="log every register read and write")
    args = parser.parse_args(argv)
    if os.geteuid() != 0:
        print("davis_gadget.py must run as root (configfs, FunctionFS)", file=sys.stderr)
        return 2
    if args.frame_every < 1:
        parser.error("--frame-every must be at least 1")
    if args.gesture_slow <= 0:
        parser.error("--gesture-slow must be positive")
    if args.hold and not args.gesture:
        parser.error("--hold follows a --gesture")
    replay = Replay(args.recording, args.loop, args.frame_every, args.from_s, args.to_s)
    cued = [
        Replay(args.recording, loop, args.frame_every, *span, args.gesture_slow)
        for loop, span in ((False, args.gesture), (True, args.hold))
        if span is not None
    ]
    load_modules()
    from functionfs.gadget import ConfigFunctionFFS, Gadget

    device = DavisDevice(replay, args.verbose, cued)
    function_class = _make_function_class()
    ffs = ConfigFunctionFFS(getFunction=lambda path: function_class(path, device))
    udcs = sorted(os.listdir("/sys/class/udc"))
    if not udcs:
        raise SystemExit("no USB device controller (dummy_hcd did not load?)")
    gadget = Gadget(
        config_list=[{"function_list": [ffs], "MaxPower": 500, "lang_dict": {0x409: {"configuration": "DAVIS"}}}],
        idVendor=VENDOR_ID,
        idProduct=PRODUCT_ID,
        bcdDevice=FIRMWARE_VERSION,
        bcdUSB=0x0200,
        lang_dict={0x409: {"manufacturer": "iniVation", "product": "DAVIS346 (emulated)", "serialnumber": args.serial}},
        name=GADGET_NAME,
        udc=udcs[0],
    )
    stop = []
    plug_requests: deque[bool] = deque()
    signal.signal(signal.SIGTERM, lambda *_: stop.append("SIGTERM"))
    signal.signal(signal.SIGINT, lambda *_: stop.append("SIGINT"))
    signal.signal(signal.SIGUSR1, lambda *_: plug_requests.append(False))
    signal.signal(signal.SIGUSR2, lambda *_: plug_requests.append(True))
    cues: deque[bool] = deque()
    signal.signal(signal.SIGHUP, lambda *_: cues.append(True))
    udc_file = CONFIGFS / "usb_gadget" / GADGET_NAME / "UDC"
    with gadget:
        device.function = ffs.function
        announced = False
        next_stats = 0.0  # when the data endpoint's counts are logged next (time.monotonic())
        with select.epoll(1) as epoll:
            epoll.register(ffs.function.eventfd, select.EPOLLIN)
            while not stop:
                try:
                    if epoll.poll(0.001):
                        process_events(ffs.function, device)
                except InterruptedError:
                    pass
                while plug_requests:
                    plug = plug_requests.popleft()
                    device.disabled("unplugged" if not plug else "re-plugged")
                    udc_file.write_text(udcs[0] if plug else "\n")
                    log("plugged in again" if plug else "unplugged (SIGUSR1)")
                    announced = announced and not plug
                while cues:
                    cues.popleft()
                    device.play_cued()
                if not announced:
                    sysdev = find_device(args.serial)
                    if sysdev is not None:
                        bus, dev = ((sysdev / n).read_text().strip() for n in ("busnum", "devnum"))
                        print(f"READY bus {bus} device {dev}", flush=True)
                        announced = True
                device.pump()
                if device.stream is not None and time.monotonic() >= next_stats:
                    log(device.stats())
                    next_stats = time.monotonic() + STATS_EVERY_S
        device.disabled("exit")  # cancels queued transfers: they would keep FunctionFS busy
        log(f"{stop[0]}: unplugging; requests seen: {device.requests}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
