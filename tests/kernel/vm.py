"""Host side of the real-kernel tests: get qemu and Debian's generic kernel, boot it once.

This machine's own kernel has no uinput (tests/kernel/README.md, "Why a kernel under qemu"), so the tests boot
Debian's generic ``linux-image-*-amd64`` under qemu with virtme-ng (``vng``), sharing the host's
root file system read-only, and run ``tests/kernel/guest.py`` inside. Two guests boot one after
the other (:func:`guest_parts`; each qemu emulates on one core, beside the host's tests on the
other: :class:`BackgroundBoot`), each running its share of the guest checks
(``tests/kernel/checks_*.py``) and writing a JSON file into a ``--rwdir`` folder; the tests assert
on the two merged.

Everything is owned by the tests: host packages are apt-installed when qemu is missing (as root),
the kernel is downloaded with ``apt-get download`` and extracted into a cache folder
(``$NEUROTOUCH_KERNEL_CACHE`` or ``~/.cache/neurotouch-hid/kernel``) that later runs reuse.
:func:`guest_results` boots at most once per Python process (the two guests), whichever test file
asks first.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import fcntl
import functools
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
GUEST_SCRIPT = HERE / "guest.py"
HOST_PACKAGES = ("qemu-system-x86", "busybox-static", "kmod", "udev")
#: Commands the boot needs, and the apt package that brings each.
HOST_COMMANDS = {
    "qemu-system-x86_64": "qemu-system-x86",
    "busybox": "busybox-static",
    "depmod": "kmod",
    "udevadm": "udev",
}
#: The guest checks that need the emulated camera (checks_davis.py: three Python starts, a few
#: minutes under emulation): the boot's shared folder then holds the replay recording.
CAMERA_MODULES = ("checks_davis",)
#: The first of the two guests booted runs the camera's checks, then these, so that
#: neither guest runs much longer than the other: beside the host's tests on 2 cores, the camera's
#: guest took 171 s and the other 610 s without them, 435 s and 315 s with them. The longer a
#: guest, the nearer its timeout on a slow machine; the host's tests took about 600 s either way.
#: They never touch the camera (their sources are files) and run after checks_davis.py unplugged it.
#: Later, beside the host's tests at load 7-10: the camera's, gamepad's and runtime's checks took
#: 150, 55 and 354 s in the first guest; the copilot's, devices', packaging's, remaps' and UHID's
#: 54, 108, 5, 312 and 104 s in the second; with the driver run in the checks' own process, the
#: USB gadget's took 245 s and the UHID output's 26 s in focused boots. So the UHID output's
#: check (no camera, no gadget) runs in the first guest.
#: The second guest runs every other module; the modules that list the cameras
#: (checks_devices.py, checks_sensor_units.py) and the larger gadget modules (checks_gadget.py,
#: checks_packaging.py) are among them, and so is checks_copilot.py (name order would run it before
#: the camera's). A fresh clone's suite beside the host's tests at load 10-16 took 884 s in the
#: first guest and 1470 s in the second, whose FunctionFS, hostile-input and road checks (88, 54
#: and 100 s there) now run in the first, after checks_davis.py has unplugged the camera and
#: freed dummy_hcd's one device controller.
FIRST_GUEST_ALSO = (
    "checks_dualsense",
    "checks_gadget_ffs",
    "checks_gamepad",
    "checks_hostile",
    "checks_road",
    "checks_runtime",
    "checks_runtime_remap",
    "checks_runtime_remap_games",
    "checks_sensors",
    "checks_type_handover",
    "checks_uhid",
)
#: Guest check modules of the slow tier only (``pytest -m slow``, :func:`slow_guest_results`, a
#: guest of their own): the gesture pipeline's numba code on the emulated camera, about 5 minutes
#: under emulation on an idle host, 8 to 17 on a loaded one.
SLOW_MODULES = ("checks_davis_pipeline",)


def guest_parts() -> list[tuple[str, ...]]:
    """The check modules (names) of each guest of the default run: :data:`CAMERA_MODULES` and
    :data:`FIRST_GUEST_ALSO`, then all the others but :data:`SLOW_MODULES`. A guest runs its
    modules in name order (``guest.py``): the camera's first. ``NEUROTOUCH_GUEST_ONLY=a,b``
    (a developer's focused run) boots one guest with just modules ``a`` and ``b``."""
    modules = sorted(path.stem for path in HERE.glob("checks_*.py"))
    only = os.environ.get("NEUROTOUCH_GUEST_ONLY", "").strip()
    if only:  # a developer's focused run: one guest with just these modules (comma-separated)
        return [tuple(sorted(m.strip() for m in only.split(",") if m.strip()))]
    first = CAMERA_MODULES + FIRST_GUEST_ALSO
    return [first, tuple(m for m in modules if m not in first + SLOW_MODULES)]


#: A guest's whole run (a limit, not a duration): the camera's pipeline checks alone took 8 to 17
#: minutes under emulation at load 7 (six commands, each a Python start of tens of seconds there),
#: the guest of all the other modules 22 minutes beside them at load 6-9 on 2 cores.
BOOT_TIMEOUT_S = 2400
#: Modules udev's coldplug would load for qemu's emulated q35 hardware (disk, CD, KVM, crypto,
#: watchdog, PS/2): none is used (the root is 9p), and loading them under software emulation costs
#: about a quarter of the boot's CPU time. ``module_blacklist=`` makes the kernel refuse them.
GUEST_MODULE_BLACKLIST = (
    "kvm_amd,kvm_intel,kvm,ccp,irqbypass,crct10dif_pclmul,crc32_pclmul,crc32c_intel,"
    "ghash_clmulni_intel,sha512_ssse3,sha256_ssse3,sha1_ssse3,sr_mod,cdrom,sg,iTCO_wdt,"
    "intel_pmc_bxt,iTCO_vendor_support,aesni_intel,crypto_simd,cryptd,ahci,libahci,libata,psmouse,"
    "i2c_i801,serio_raw,i2c_smbus,pcspkr,lpc_ich,i6300esb,watchdog,scsi_mod"
)


class KernelUnavailable(Exception):
    """qemu (or the kernel) cannot be had on this machine at all: the tests skip with this reason."""


def cache_dir() -> Path:
    """The folder the tests own for the extracted kernel (created)."""
    root = os.environ.get("NEUROTOUCH_KERNEL_CACHE")
    if root:
        path = Path(root)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        path = Path(xdg) / "neurotouch-hid" / "kernel"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


#: How long an apt-get call waits for a lock another apt holds (s): on a freshly booted machine
#: unattended-upgrades or a first ``apt-get update`` can hold the dpkg or the lists lock for minutes.
APT_LOCK_WAIT_S = 600.0
#: apt-get's words when another process holds one of its locks (dpkg's, the lists', the archives').
APT_LOCKED = "Could not get lock"


def apt_get(args: list[str], wait_s: float = APT_LOCK_WAIT_S, **kw) -> subprocess.CompletedProcess:
    """``apt-get ARGS``, tried again every 2 s for up to ``wait_s`` while another process holds a
    lock apt-get needs (it fails at once with :data:`APT_LOCKED` otherwise, exit code 100).

    Returns the last try's completed process (text output captured); ``kw`` go to
    ``subprocess.run``."""
    deadline = time.monotonic() + wait_s
    while True:
        done = _run(["apt-get", *args], **kw)
        if done.returncode == 0 or APT_LOCKED not in done.stderr or time.monotonic() >= deadline:
            return done
        time.sleep(2.0)


def _which(cmd: str) -> str | None:
    return shutil.which(cmd) or shutil.which(cmd, path="/usr/sbin:/sbin:/usr/bin:/bin")


def _apt_install(packages: list[str]) -> tuple[subprocess.CompletedProcess, subprocess.CompletedProcess]:
    """``apt-get update``, then ``apt-get install`` of ``packages`` without recommends, both
    non-interactive and waiting for another apt's lock (:func:`apt_get`): (update, install)."""
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    update = apt_get(["update"], env=env)
    return update, apt_get(["install", "-y", "--no-install-recommends", *packages], env=env)


def installed(command: str, package: str) -> str | None:
    """The path of ``command``; when it is missing and this runs as root with apt-get, ``package``
    is apt-installed first (:func:`_apt_install`). None when it is still missing."""
    found = _which(command)
    if found is None and os.geteuid() == 0 and _which("apt-get"):
        _apt_install([package])
        found = _which(command)
    return found


def ensure_host_packages() -> None:
    """apt-get install qemu, busybox, kmod and udev when one of their commands is missing, and
    libaio1 when the library is (functionfs, which davis_gadget.py uses, loads it).

    Raises KernelUnavailable when they are missing and cannot be installed (not root, no apt,
    apt fails, or another apt held its lock for :data:`APT_LOCK_WAIT_S`)."""
    missing = sorted({pkg for cmd, pkg in HOST_COMMANDS.items() if _which(cmd) is None})
    if ctypes.util.find_library("aio") is None:  # functionfs (davis_gadget.py) loads libaio
        missing.append("libaio1")
    if not missing:
        return
    if os.geteuid() != 0 or _which("apt-get") is None:
        raise KernelUnavailable(
            f"{', '.join(missing)} not installed and cannot be apt-installed here (needs root and apt-get)"
        )
    update, install = _apt_install([*HOST_PACKAGES, *(["libaio1"] if "libaio1" in missing else [])])
    if install.returncode != 0 or _which("qemu-system-x86_64") is None:
        raise KernelUnavailable("apt-get install of qemu failed: " + (install.stderr or update.stderr).strip()[-500:])


def _kernel_package_name() -> str:
    """The generic (not cloud) kernel package that linux-image-amd64 depends on right now."""
    for attempt in range(2):
        out = _run(["apt-cache", "depends", "linux-image-amd64"])
        for line in out.stdout.splitlines():
            word = line.split(":", 1)[-1].strip()
            if (
                line.strip().startswith("Depends:")
                and word.startswith("linux-image-")
                and word.endswith("-amd64")
                and "cloud" not in word
            ):
                return word
        if attempt == 0:
            apt_get(["update"])
    raise KernelUnavailable(
        "apt-cache cannot name Debian's generic kernel package "
        "(linux-image-amd64 has no linux-image-*-amd64 dependency)"
    )


def _cached_kernel(root: Path) -> tuple[Path, str] | None:
    done = sorted(root.glob("linux-image-*/.complete"), key=lambda p: p.stat().st_mtime)
    if not done:
        return None
    kdir = done[-1].parent
    return kdir, kdir.name.removeprefix("linux-image-")


def ensure_kernel() -> tuple[Path, str]:
    """(extracted kernel folder, kernel release); downloads and extracts on the first call.

    Reuses any complete extraction in :func:`cache_dir` (no apt access then). A file lock keeps
    parallel test sessions from extracting twice."""
    root = cache_dir()
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        cached = _cached_kernel(root)
        if cached:
            return cached
        pkg = _kernel_package_name()
        kver = pkg.removeprefix("linux-image-")
        kdir = root / pkg
        with tempfile.TemporaryDirectory(dir=root) as tmp:
            dl = apt_get(["download", pkg], cwd=tmp)
            debs = list(Path(tmp).glob(f"{pkg}_*.deb"))
            if dl.returncode != 0 or not debs:
                raise RuntimeError(f"apt-get download {pkg} failed: {dl.stderr.strip()[-500:]}")
            shutil.rmtree(kdir, ignore_errors=True)
            subprocess.run(["dpkg-deb", "-x", str(debs[0]), str(kdir)], check=True)
        subprocess.run([_which("depmod") or "depmod", "-b", str(kdir), kver], check=True)
        (kdir / ".complete").write_text(pkg + "\n")
        return kdir, kver


#: A newer systemd than the host's (Debian 12's 252) for checks_user_unit.py: Debian 12's backports
#: (254). From systemd 253 a user's manager runs a unit that asks for namespaces in a user
#: namespace of its own, which 252 never does: the user unit must be checked under both.
NEWER_SYSTEMD_SOURCE = (
    "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] "
    "http://deb.debian.org/debian bookworm-backports main"
)
NEWER_SYSTEMD_PACKAGES = ("systemd/bookworm-backports", "libsystemd-shared/bookworm-backports")
#: Its folder's name in :func:`cache_dir` and in a boot's shared folder (the packages extracted).
NEWER_SYSTEMD = "systemd-newer"
#: The check modules that need it in their boot's shared folder.
NEWER_SYSTEMD_MODULES = ("checks_user_unit",)


def ensure_newer_systemd() -> Path:
    """The folder with :data:`NEWER_SYSTEMD_PACKAGES` extracted (``lib/systemd/systemd``,
    ``bin/systemctl``, ``usr/lib/x86_64-linux-gnu/systemd/libsystemd-shared-*.so``), downloaded
    on the first call by apt-get with a sources list of its own (signatures checked against
    Debian's keyring; the host's apt configuration is not touched), then cached.

    Raises RuntimeError with apt-get's words when the download fails."""
    root = cache_dir()
    folder = root / NEWER_SYSTEMD
    with open(root / ".lock-systemd", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (folder / ".complete").exists():
            return folder
        with tempfile.TemporaryDirectory(dir=root) as tmp:
            work = Path(tmp)
            for sub in ("lists/partial", "cache/archives/partial", "parts"):
                (work / sub).mkdir(parents=True)
            (work / "sources.list").write_text(NEWER_SYSTEMD_SOURCE + "\n")
            options = []
            for key, value in (
                ("Dir::Etc::SourceList", work / "sources.list"),
                ("Dir::Etc::SourceParts", work / "parts"),
                ("Dir::State::Lists", work / "lists"),
                ("Dir::Cache", work / "cache"),
                ("APT::Sandbox::User", "root"),
            ):
                options += ["-o", f"{key}={value}"]
            for args in (["update"], ["download", *NEWER_SYSTEMD_PACKAGES]):
                done = apt_get([*options, *args], cwd=tmp)
                if done.returncode != 0:
                    raise RuntimeError(f"apt-get {args[0]} ({NEWER_SYSTEMD_SOURCE}) failed: {done.stderr[-800:]}")
            debs = sorted(work.glob("*.deb"))
            if len(debs) != len(NEWER_SYSTEMD_PACKAGES):
                raise RuntimeError(f"apt-get download {NEWER_SYSTEMD_PACKAGES} gave {[d.name for d in debs]}")
            extracted = work / "root"
            for deb in debs:
                subprocess.run(["dpkg-deb", "-x", str(deb), str(extracted)], check=True)
            shutil.rmtree(folder, ignore_errors=True)
            extracted.rename(folder)
        (folder / ".complete").write_text("".join(d.name + "\n" for d in debs))
        return folder


def _vng() -> str:
    bindir = Path(sys.executable).parent
    found = shutil.which("vng", path=str(bindir)) or shutil.which("vng")
    if not found:
        raise RuntimeError("vng not found: pip install virtme-ng (it is in the [test] extras)")
    return found


#: The recording checks_davis.py replays as an emulated DAVIS-346: the simulated gel at rest, 2 s
#: (made once on the host with the project's own simulator, then cached).
REPLAY_RECORDING = "replay-gel-rest-2s-seed0.aedat4"


def ensure_replay_recording() -> Path:
    """The cached gel recording for the emulated camera, made by ``neurotouch-hid record --source
    sim --fast`` on the first call. Raises RuntimeError (with the command's output) if that fails."""
    path = cache_dir() / REPLAY_RECORDING
    if path.exists():
        return path
    cli = Path(sys.executable).parent / "neurotouch-hid"
    tmp = path.with_suffix(".part.aedat4")
    proc = _run(
        [str(cli), "record", "--source", "sim", "--fast", "--seconds", "2", "--seed", "0", "--force", str(tmp)],
        cwd=str(HERE.parent.parent),
    )
    if proc.returncode != 0 or not tmp.exists():
        raise RuntimeError(f"making the replay recording failed: {proc.stdout[-1000:]}{proc.stderr[-1000:]}")
    tmp.rename(path)
    return path


#: numba's settings for the pipeline's code compiled on the host for the guest (checks_davis.py
#: runs ``run --source davis``): compiling it under emulation takes longer than 600 s, so the host
#: compiles it before the boot into the shared folder. numba keys a cached function on the target
#: CPU's name and features (``CPUCodegen.magic_tuple``): the host's CPU name (znver5 here) and the
#: guest's (qemu's "max" model under TCG: k8-sse3 with AVX2) differ, so both use LLVM's "generic"
#: x86-64 CPU, whose feature string numba then leaves empty: the same key on both sides.
GUEST_NUMBA_ENV = {"NUMBA_CPU_NAME": "generic"}
#: Name of that cache folder in the boot's shared folder.
GUEST_NUMBA_CACHE = "numba-cache"


def compile_guest_numba_cache(folder: Path) -> None:
    """Compile the gesture pipeline's numba code (``warmup.compile_pipeline``) into ``folder`` for
    the guest (GUEST_NUMBA_ENV). Raises RuntimeError with the output if that fails."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(folder), **GUEST_NUMBA_ENV)
    proc = _run(
        [sys.executable, "-c", "from neurotouch_hid.service.warmup import compile_pipeline; compile_pipeline()"],
        env=env,
        cwd=str(HERE.parent.parent),
    )
    if proc.returncode != 0:
        raise RuntimeError(f"compiling the pipeline for the guest failed: {proc.stdout[-1000:]}{proc.stderr[-1000:]}")


#: How long a guest may take to start ``guest.py`` (the :data:`GUEST_STARTED` file it writes first
#: in the shared folder): about 20 s on an idle host, a few minutes beside the host's tests or the
#: other guest. A guest that has not started it by then is stuck in the kernel's boot or in
#: virtme-ng's init, before any of the project's code runs: it is stopped and booted once more.
GUEST_START_TIMEOUT_S = 600
#: The file ``guest.py`` writes into the shared folder before anything else.
GUEST_STARTED = "guest-started"


def boot(
    guest_script: Path = GUEST_SCRIPT,
    timeout_s: int = BOOT_TIMEOUT_S,
    cancelled: threading.Event | None = None,
    modules: tuple[str, ...] = (),
    start_timeout_s: float = GUEST_START_TIMEOUT_S,
) -> dict:
    """Boot the kernel under qemu (no KVM), run ``guest_script`` in it (on the check ``modules``
    only, when given), return its JSON.

    When the camera's checks run (checks_davis.py, checks_davis_pipeline.py), the boot's shared
    folder holds, beside the result, what they need: the replay recording, and for the pipeline's
    runs its numba code compiled here (:func:`compile_guest_numba_cache`).
    The JSON maps each check's name to ``{"ok": bool, "seconds": float, ...details}``, plus
    ``"_boot"`` with the boot's wall time and kernel release. A guest that has not started
    ``guest_script`` within ``start_timeout_s`` is booted once more; ``"_boot"`` then says so under
    ``"retried"``, with the end of the first boot's console.

    Raises KernelUnavailable when qemu cannot be installed, RuntimeError (with the end of vng's
    output: the kernel's console and the guest's progress) when the guest wrote no result.
    ``cancelled`` (set from another thread, :func:`cancel_background_boot`) stops qemu early: the
    boot then raises RuntimeError."""
    ensure_host_packages()
    kdir, kver = ensure_kernel()
    vmlinuz = kdir / "boot" / f"vmlinuz-{kver}"
    cancelled = cancelled or threading.Event()
    out = Path(tempfile.mkdtemp(prefix="boot-", dir=cache_dir()))
    if not modules or any(m in CAMERA_MODULES + SLOW_MODULES for m in modules):
        shutil.copyfile(ensure_replay_recording(), out / "davis_replay.aedat4")  # checks_davis.py's camera
    if not modules or any(m in SLOW_MODULES for m in modules):
        compile_guest_numba_cache(out / GUEST_NUMBA_CACHE)  # the pipeline's code for its runs
    if not modules or any(m in NEWER_SYSTEMD_MODULES for m in modules):  # checks_user_unit.py's manager
        shutil.copytree(ensure_newer_systemd(), out / NEWER_SYSTEMD, symlinks=True)
    result = out / "result.json"
    inner = " ".join(shlex.quote(s) for s in (sys.executable, str(guest_script), str(result), *modules))
    cmd = [
        _vng(),
        "--disable-kvm",
        "--verbose",  # the kernel's console in the log: where a boot that never ends stopped
        "--run",
        str(vmlinuz),
        "--memory",
        "1G",
        "--append",
        f"module_blacklist={GUEST_MODULE_BLACKLIST}",
        f"--rwdir={out}",
        "--exec",
        inner,
    ]
    log, seconds, stopped = _run_vng(cmd, out, timeout_s, start_timeout_s, cancelled)
    retried = None
    if stopped == NEVER_STARTED:  # stuck before any of the project's code ran: the same boot once more
        (out / "vng-first-boot.log").write_text(log)
        retried = f"{NEVER_STARTED} within {start_timeout_s:.0f} s; its console ended with:\n{log[-1500:]}"
        log, seconds, stopped = _run_vng(cmd, out, timeout_s, start_timeout_s, cancelled)
    (out / "vng.log").write_text(log)
    if not result.exists():
        again = "" if retried is None else f", booted twice (the first time: {retried})"
        raise RuntimeError(f"the guest wrote no {result.name}{again}; vng said:\n{log[-3000:]}")
    data = json.loads(result.read_text())
    data["_boot"] = {"seconds": round(seconds, 1), "kernel": kver, "modules": list(modules)}
    if retried is not None:
        data["_boot"]["retried"] = retried
    if not _failed_anywhere(data):
        shutil.rmtree(out, ignore_errors=True)
    else:
        data["_boot"]["out_dir"] = str(out)  # kept: result.json and the vng logs, to look at
    return data


#: Why :func:`_run_vng` stopped a guest that never started ``guest.py``.
NEVER_STARTED = "the guest never started guest.py"
#: A process of its own beside each vng (:func:`_run_vng`): every second it checks that the test
#: process that started it is still its parent, and when it is not (that process was killed, its
#: cleanup never ran) it kills vng's process group, qemu with it, instead of leaving the guest
#: running with both cores; it ends with the group. argv: the test process's pid, vng's group.
WATCHDOG = """
import os, signal, sys, time
parent, group = int(sys.argv[1]), int(sys.argv[2])
while True:
    time.sleep(1.0)
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        break
    if os.getppid() != parent:
        os.killpg(group, signal.SIGKILL)
        break
"""


def _run_vng(
    cmd: list[str], out: Path, timeout_s: float, start_timeout_s: float, cancelled: threading.Event
) -> tuple[str, float, str]:
    """Run ``cmd`` (vng) until it exits, or stop its whole process group: when ``cancelled`` is
    set, when ``timeout_s`` has passed, or when ``start_timeout_s`` has passed without the
    :data:`GUEST_STARTED` file in ``out``; a :data:`WATCHDOG` stops it when this process is killed
    first. Returns (its output, wall seconds, why it was stopped: "" when it exited,
    :data:`NEVER_STARTED` for the last case)."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '/usr/bin:/bin')}"
    t0 = time.monotonic()
    with (
        tempfile.TemporaryFile("w+") as log_file,
        subprocess.Popen(
            cmd,
            stdout=log_file,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            stdin=subprocess.DEVNULL,
            cwd=str(HERE.parent.parent),
            start_new_session=True,  # vng, qemu and all: one process group, to stop them together
        ) as proc,
    ):
        # in a session of its own too: a signal to the test's process group leaves it to do its job
        watchdog = subprocess.Popen(
            [sys.executable, "-c", WATCHDOG, str(os.getpid()), str(proc.pid)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        try:
            stopped = ""
            while proc.poll() is None and not stopped:
                if cancelled.wait(1.0):  # a 1 s tick, not a spin: qemu needs both cores
                    stopped = "the test session ended first"
                elif time.monotonic() - t0 > timeout_s:
                    stopped = f"vng timed out after {timeout_s} s"
                elif time.monotonic() - t0 > start_timeout_s and not (out / GUEST_STARTED).exists():
                    stopped = NEVER_STARTED
            if stopped:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        finally:  # also on an exception here (Ctrl-C): the guest does not outlive the wait for it
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            watchdog.kill()
            watchdog.wait()
        log_file.seek(0)
        log = (f"{stopped}\n" if stopped else "") + log_file.read()
    return log, time.monotonic() - t0, stopped


def _failed_anywhere(entry) -> bool:
    """Whether a result, or any part of one at any depth (checks_davis.py's parts), says ``"ok": false``."""
    if isinstance(entry, dict):
        return entry.get("ok") is False or any(_failed_anywhere(value) for value in entry.values())
    return False


def merge_results(parts: list[dict]) -> dict:
    """One result from the guests' results: every check's entry, and ``_boot`` with the longest
    boot's seconds, the kernel and each guest's own ``_boot`` (``parts``)."""
    merged: dict = {}
    for part in parts:
        merged.update({name: entry for name, entry in part.items() if name not in ("_boot", "_guest", "setup")})
    boots = [part.get("_boot", {}) for part in parts]
    merged["setup"] = next((p["setup"] for p in parts if not p.get("setup", {}).get("ok", True)), parts[0].get("setup"))
    merged["_boot"] = {
        "seconds": max(b.get("seconds", 0) for b in boots),
        "kernel": boots[0].get("kernel"),
        "parts": boots,
    }
    return merged


class BackgroundBoot:
    """The guests of :func:`guest_parts`, each :func:`boot` in a thread started as the test session
    starts, so that the host's tests run while the guests do (a boot takes minutes under software
    emulation): one after the other in one thread, or side by side, a thread each.

    Each qemu emulates on one core. The suite's default is side by side: the guests' checks now
    take longer than the host's tests (about 950 s of guest checks against about 600 s of host
    tests, 2026-11-29), so one guest after the other left a core idle once the host's tests were
    done, and the suite's time was the two guests' sum (1,108 s at load 5-9). Side by side, the
    three share the two cores until the first ends."""

    def __init__(self, side_by_side: bool = False) -> None:
        self._cancelled = threading.Event()
        self._parts = guest_parts()
        self._results: list[dict | None] = [None] * len(self._parts)
        self._first_error: BaseException | None = None  # not the other guest's cancellation after it
        self._lock = threading.Lock()
        indices = [[i] for i in range(len(self._parts))] if side_by_side else [list(range(len(self._parts)))]
        self._threads = [
            threading.Thread(target=self._boot, args=(each,), name=f"kernel-boot-{each[0]}", daemon=True)
            for each in indices
        ]
        for thread in self._threads:
            thread.start()

    def _boot(self, indices: list[int]) -> None:
        try:
            for index in indices:
                self._results[index] = boot(cancelled=self._cancelled, modules=self._parts[index])
        except BaseException as exc:  # noqa: BLE001 - handed to the thread that asks for the result
            with self._lock:
                self._first_error = self._first_error or exc
            self._cancelled.set()  # the other guests' results alone would not do

    def result(self) -> dict:
        """The guests' merged JSON once both are done (:func:`merge_results`); raises what a
        :func:`boot` raised."""
        for thread in self._threads:
            thread.join()
        if self._first_error is not None:
            raise self._first_error
        return merge_results([r for r in self._results if r is not None])

    @property
    def finished(self) -> dict | None:
        """The merged JSON if both guests finished with one, else None (without waiting)."""
        if any(r is None for r in self._results):
            return None
        return merge_results(self._results)

    def cancel(self) -> None:
        """Stop qemu if it still runs (the session ended before any test asked for the result)."""
        self._cancelled.set()
        for thread in self._threads:
            thread.join(timeout=30)


_background: BackgroundBoot | None = None


def start_background_boot(side_by_side: bool = False) -> None:
    """Start the one boot of this process now, in the background (:class:`BackgroundBoot`: the
    guests one after the other, or ``side_by_side``)."""
    global _background
    if _background is None:
        _background = BackgroundBoot(side_by_side)


def boot_summary() -> str | None:
    """One line on the finished background boot: its wall time and each guest check's seconds
    (and the guest's CPU seconds meanwhile), slowest first (None when no boot finished). For the
    test session's summary: CI shows where the guest's minutes go."""
    result = _background.finished if _background is not None else None
    if result is None:
        return None
    checks = sorted(
        (
            (name, entry["seconds"], entry.get("cpu_s"))
            for name, entry in result.items()
            if isinstance(entry, dict) and "seconds" in entry and not name.startswith("_")
        ),
        key=lambda item: -item[1],
    )
    listed = ", ".join(
        f"{name.split('.')[-1]} {seconds:.0f} s" + ("" if cpu is None else f" (cpu {cpu:.0f} s)")
        for name, seconds, cpu in checks
    )
    boots = ", ".join(
        f"{b.get('seconds', '?')} s ({' '.join(b.get('modules') or ['all'])})" for b in result["_boot"].get("parts", [])
    )
    retries = [b["retried"].splitlines()[0] for b in result["_boot"].get("parts", []) if b.get("retried")]
    again = "".join(f"; booted again: {reason}" for reason in retries)
    return f"kernel boots {boots}{again}; guest checks: {listed}"


def cancel_background_boot() -> None:
    """Stop a background boot that is still running (nothing when none was started)."""
    if _background is not None:
        _background.cancel()


@functools.cache
def slow_guest_results() -> dict:
    """The results of one boot of :data:`SLOW_MODULES` per Python process (the slow tier's guest).

    Raises KernelUnavailable or RuntimeError as :func:`boot` does."""
    return boot(modules=SLOW_MODULES)


@functools.cache
def guest_results() -> dict:
    """The merged results of the one pair of boots per Python process (one pytest session): the
    background ones' when they were started, else both booted now; later calls get the same dict.

    Raises KernelUnavailable (tests skip with its message) or RuntimeError (tests fail)."""
    return (_background if _background is not None else BackgroundBoot(side_by_side=True)).result()
