"""Which camera a run stands for, and that camera's own config files.

A run (``neurotouch-hid run``) stands for one camera, known by its serial: the live DAVIS-346
(``--serial``, else the only one on the bus), the simulated one (``--source sim --serial X``) or
the camera a recording is replayed as. The serial gives the outputs their identity
(:func:`~neurotouch_hid.targets.identity.identity_for`) and picks the camera's own config
folder (:mod:`neurotouch_hid.service.serials`, docs/several-sensors.md).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.kinds import SourceKind

if TYPE_CHECKING:
    from neurotouch_hid.sources.davis import DavisConfig

log = logging.getLogger(__name__)


def camera_serial(
    source: str,
    serial: str | None,
    davis: DavisConfig | None = None,
    say: Callable[[str], None] = log.warning,
) -> str | None:
    """The serial of the camera a run stands for: ``serial`` (``--serial``: the live camera to
    open, the simulated camera's, or the camera a recording is replayed as), else the live
    camera's ``davis.serial``, else, for the live camera, the USB serial number of the one
    DAVIS-346 on the bus (:func:`~neurotouch_hid.sources.discovery.discover` without
    dv-processing; several: None, said once; none: None, the run waits or fails as before).
    None: no serial, the default identity and the shared config.

    Raises:
        NeurotouchError: ``serial`` is not a valid serial
            (:func:`~neurotouch_hid.service.serials.check_serial`).
    """
    from neurotouch_hid.service.serials import check_serial

    given = serial if serial is not None else (davis.serial if davis is not None else None)
    if given is not None:
        try:
            return check_serial(given)
        except ValueError as exc:
            raise NeurotouchError(f"--serial: {exc}") from None
    if source != SourceKind.DAVIS:
        return None
    from neurotouch_hid.sources.discovery import discover

    # pyusb and sysfs (the USB serial string, readable by anyone), not dv-processing: nothing opened
    serials = [c.serial for c in discover(dv=False).davis346 if c.serial]
    if len(serials) > 1:
        say(
            f"{len(serials)} DAVIS-346 cameras ({', '.join(serials)}): this run opens the first it can and its "
            "controller has the default identity; give --serial SERIAL to run one per camera"
        )
        return None
    if serials:
        try:
            return check_serial(serials[0])
        except ValueError as exc:
            say(f"the camera's serial is not used for its controller's identity: {exc}")
    return None


def own_config(
    source: str, serial: str | None, profile: str | Path | None, sensor: str | Path | None
) -> tuple[str | Path, str | Path | None]:
    """``(profile, sensor)`` for a run of the camera ``serial``: ``profile`` as given, else the
    camera's own ``profile.yaml``, else ``"default"``; ``sensor`` as given, else (the live camera
    and the simulated gel, whose geometry is the camera's) its own ``sensor.yaml``, else None
    (the shared calibration, as before; a recording's own sensor.yaml beside it comes first).
    (:mod:`neurotouch_hid.service.serials`; docs/several-sensors.md.)"""
    from neurotouch_hid.service.serials import own_file

    if profile is None:
        profile = own_file(serial, "profile") or "default"
    if sensor is None and source in (SourceKind.DAVIS, SourceKind.SIM):
        sensor = own_file(serial, "sensor")
    return profile, sensor
