"""Which input device a profile's ``copilot:`` entry means: by name, by USB ids, by a stable path.

The system's input devices are read from sysfs (``/sys/class/input/eventN/device``: ``name``,
``phys``, ``id/vendor``, ``id/product``; Documentation/ABI/testing/sysfs-class-input), each
attribute within :data:`MAX_ATTRIBUTE_BYTES` (:func:`~neurotouch_hid.core.limits.read_proc_file`), so
that listing needs no permission on the device nodes. udev's stable links
(``/dev/input/by-id/*``, ``by-path/*``) are resolved to the nodes they name.

The driver's own devices (the pad, keyboard and mouse it makes: ``phys`` ``neurotouch-hid/...``,
:data:`~neurotouch_hid.targets.uinput.gamepad.PHYS`) never match any rule.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from neurotouch_hid.core.limits import printable, read_proc_file

#: Where evdev nodes live, and udev's stable links to them.
INPUT_DIR = Path("/dev/input")
STABLE_DIRS = ("by-id", "by-path")
SYSFS_INPUT = Path("/sys/class/input")
#: Longest sysfs attribute read (a device name is at most a few hundred bytes).
MAX_ATTRIBUTE_BYTES = 4096
#: Every device the driver makes has a ``phys`` starting so (the udev rule tags them too).
OWN_PHYS_PREFIX = "neurotouch-hid/"
_EVENT = re.compile(r"^event(\d+)$")
_IDS = re.compile(r"^([0-9a-f]{4}):([0-9a-f]{4})$")


@dataclass(frozen=True)
class InputInfo:
    """One evdev device of the system.

    Attributes:
        path: its node, ``/dev/input/eventN``.
        name, phys: as the kernel reports them (printable; ``phys`` may be empty).
        vendor, product: its ids (USB's for a USB device), 0 when unknown.
        links: the stable links (``/dev/input/by-id/...``, ``by-path/...``) naming it.
    """

    path: str
    name: str
    phys: str = ""
    vendor: int = 0
    product: int = 0
    links: tuple[str, ...] = ()

    @property
    def ids(self) -> str:
        """``vvvv:pppp``, lower-case hex."""
        return f"{self.vendor:04x}:{self.product:04x}"

    @property
    def own(self) -> bool:
        """One of the driver's own devices (never merged)."""
        return self.phys.startswith(OWN_PHYS_PREFIX)

    @property
    def number(self) -> int:
        """N of ``eventN`` (for a stable order)."""
        found = _EVENT.match(os.path.basename(self.path))
        return int(found.group(1)) if found else 1 << 30


def _attribute(folder: Path, name: str) -> str:
    try:
        data, _ = read_proc_file(folder / name, MAX_ATTRIBUTE_BYTES)
    except OSError:
        return ""
    return printable(data.decode("utf-8", "replace").strip(), 255)


def _hex(text: str) -> int:
    try:
        return int(text, 16) & 0xFFFF
    except ValueError:
        return 0


def stable_links(input_dir: Path = INPUT_DIR) -> dict[str, list[str]]:
    """Node (``/dev/input/eventN``) -> the stable links naming it (sorted)."""
    found: dict[str, list[str]] = {}
    for sub in STABLE_DIRS:
        folder = input_dir / sub
        try:
            entries = sorted(os.listdir(folder))
        except OSError:
            continue
        for entry in entries:
            link = folder / entry
            try:
                target = os.path.realpath(link)
            except OSError:
                continue
            found.setdefault(target, []).append(str(link))
    return found


def input_devices(input_dir: Path = INPUT_DIR, sysfs: Path = SYSFS_INPUT) -> list[InputInfo]:
    """Every ``eventN`` node of ``input_dir`` with its sysfs description, in N order (the
    driver's own included: see :attr:`InputInfo.own`)."""
    try:
        names = [n for n in os.listdir(input_dir) if _EVENT.match(n)]
    except OSError:
        return []
    links = stable_links(input_dir)
    out = []
    for node in names:
        folder = sysfs / node / "device"
        path = str(input_dir / node)
        out.append(
            InputInfo(
                path=path,
                name=_attribute(folder, "name"),
                phys=_attribute(folder, "phys"),
                vendor=_hex(_attribute(folder, "id/vendor")),
                product=_hex(_attribute(folder, "id/product")),
                links=tuple(links.get(os.path.realpath(path), ())),
            )
        )
    return sorted(out, key=lambda info: info.number)


def matches(rule: str, info: InputInfo) -> bool:
    """Whether ``copilot:``'s ``device: rule`` names ``info``: a path under ``/dev/input/`` (a
    stable link or the node itself), ``vvvv:pppp`` (its ids, any case), else its exact name.
    The driver's own devices never match."""
    if info.own:
        return False
    if rule.startswith("/"):
        return rule == info.path or rule in info.links
    ids = _IDS.match(rule.lower())
    if ids:
        return info.vendor == int(ids.group(1), 16) and info.product == int(ids.group(2), 16)
    return rule == info.name


def mergeable_devices(input_dir: Path = INPUT_DIR, sysfs: Path = SYSFS_INPUT) -> list[InputInfo]:
    """The input devices a profile's ``copilot:`` could name: every evdev device but the
    driver's own, in node order."""
    return [info for info in input_devices(input_dir, sysfs) if not info.own]


def presence(rules: list[str], devices: list[InputInfo]) -> list[tuple[str, InputInfo | None]]:
    """Each ``copilot:`` rule with the device it names among ``devices`` (None: missing); a device
    is taken by the first rule naming it, as the running driver takes it."""
    free = list(devices)
    out: list[tuple[str, InputInfo | None]] = []
    for rule in rules:
        found = next((info for info in free if matches(rule, info)), None)
        if found is not None:
            free.remove(found)
        out.append((rule, found))
    return out


def presence_line(rules: list[str], devices: list[InputInfo]) -> str:
    """One line for the user: ``present: NAME (NODE), ...; missing: NAME, ...`` (a missing device
    is waited for by the running driver, and merged when it comes)."""
    found = presence(rules, devices)
    present = [f"{rule} ({info.path})" for rule, info in found if info is not None]
    missing = [rule for rule, info in found if info is None]
    return f"present: {', '.join(present) or 'none'}; missing: {', '.join(missing) or 'none'}"


def to_json(info: InputInfo) -> dict:
    """``info`` for ``devices --json``: the name, ids and stable links to write in ``copilot:``."""
    return {"node": info.path, "name": info.name, "ids": info.ids, "phys": info.phys, "links": list(info.links)}
