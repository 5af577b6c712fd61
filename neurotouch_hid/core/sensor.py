"""Sensor geometry: the gel's place in the image, image <-> user frame, px <-> mm.

The geometry is the ``sensor.yaml`` of docs/dataset.md. The *image frame* is pixels, x right, y down,
origin at the top-left pixel's centre. The *user frame* is the gel seen from outside and above,
millimetres, x right, y up, origin at the gel's centre. The camera looks at the gel from inside
(paper, section "System Overview"), so the image is the mirror of what the user sees::

    d = ((u - cx), -(v - cy)) / px_per_mm          # image as displayed, y up, mm
    d = d (1 + k1 x^2 + k2 x^4)   with radial_k     # the camera model, x = image radius / gel radius
    d = (-d.x, d.y)            if mirror            # the camera looks from inside
    user = rotate(d, rotation_deg)                  # counter-clockwise, degrees

The camera model (``radial_k`` = (k1, k2), not in the paper): the dome's rim is nearer the
camera than its apex and the lens distorts, so px/mm is not one number over the image. A
radial polynomial about the gel's centre (Brown-Conrady's radial terms, Brown 1966, here from
image to gel) maps the image radius to the user frame's radius; ``calibrate`` (and the pipeline,
from its rest frame, when sensor.yaml has none) fits it to the 4 mm marker grid at rest
(:mod:`neurotouch_hid.core.camera_model`). Without it (None) the mapping is the linear one above.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    TypeAdapter,
    ValidationError,
    with_config,
)
from ruamel.yaml.nodes import MappingNode
from typing_extensions import TypedDict  # pydantic needs typing_extensions' TypedDict before 3.12

from neurotouch_hid.core.atomic import AtomicFile
from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.limits import (
    MAX_SENSOR_PX,
    MAX_YAML_BYTES,
    YamlError,
    load_yaml,
    read_outside_text,
    short,
    where,
)

#: DAVIS-346 resolution (px).
DAVIS346_WIDTH = 346
DAVIS346_HEIGHT = 260
#: Radius of the sphere the NeuroTouch dome is a cap of (mm): 13.5 mm high over its 30 mm base
#: radius. The simulator's gel and the camera model (``camera_model.py``) both lie on it.
DOME_SPHERE_MM = 40.0
#: The pitch of the gel's marker grid on its surface (mm; paper, section "System Overview").
MARKER_SPACING_MM = 4.0


#: A position in the image (px): the gel's centre may lie a little outside the image, never
#: further than an image is wide (1e300 ended in an OverflowError traceback).
_Px = Annotated[float, Field(ge=-MAX_SENSOR_PX, le=MAX_SENSOR_PX)]
#: A radial term of the camera model (dimensionless, over the normalised radius): real lenses
#: have |k| well under 1.
_Coefficient = Annotated[float, Field(ge=-100, le=100)]
#: The camera model must map the image radius one to one out to this many gel radii (the gel and
#: a margin for markers tracked past its rim): :meth:`SensorGeometry.distort` inverts it there.
MONOTONE_TO_RADII = 1.25


def one_to_one(radial_k: tuple[float, float]) -> tuple[float, float]:
    """``radial_k`` when ``r (1 + k1 x^2 + k2 x^4)`` grows with r for x = r / gel radius up to
    :data:`MONOTONE_TO_RADII` (its derivative ``1 + 3 k1 x^2 + 5 k2 x^4`` stays positive); else
    ValueError (a folded model maps two radii of the gel to one)."""
    k1, k2 = radial_k
    x2 = np.linspace(0.0, MONOTONE_TO_RADII**2, 201)
    if not np.all(1.0 + 3.0 * k1 * x2 + 5.0 * k2 * x2 * x2 > 0.0):
        raise ValueError(
            f"expected a camera model whose radius grows with the image radius out to {MONOTONE_TO_RADII:g} gel radii "
            "(1 + 3 k1 x^2 + 5 k2 x^4 > 0; calibrate fits one)"
        )
    return radial_k


@with_config(ConfigDict(allow_inf_nan=False))
class SensorFile(TypedDict, total=False):
    """The fields of a ``sensor.yaml`` as read from the file (docs/dataset.md), each optional (a
    missing one takes :class:`SensorGeometry`'s default), checked by pydantic (:data:`_SENSOR_FILE`):
    a whole number of px, a positive number, a pair of numbers, true/false; every number finite,
    sizes and positions at most :data:`~neurotouch_hid.core.limits.MAX_SENSOR_PX`, a rotation within
    one turn, a creep time at most an hour (docs/limits.md)."""

    width: Annotated[StrictInt, Field(gt=0, le=MAX_SENSOR_PX)]
    height: Annotated[StrictInt, Field(gt=0, le=MAX_SENSOR_PX)]
    px_per_mm: Annotated[float, Field(gt=0, le=MAX_SENSOR_PX)]
    gel_center_px: tuple[_Px, _Px]
    gel_radius_px: Annotated[float, Field(gt=0, le=MAX_SENSOR_PX)]
    mirror: StrictBool
    rotation_deg: Annotated[float, Field(ge=-360, le=360)]
    radial_k: Annotated[tuple[_Coefficient, _Coefficient], AfterValidator(one_to_one)]
    creep: tuple[Annotated[float, Field(ge=0, lt=1)], Annotated[float, Field(gt=0, le=3600)]]


_SENSOR_FILE = TypeAdapter(SensorFile)


def _key_lines(root: Any) -> dict[str, int]:
    """The 1-based line of each top-level key of a YAML mapping node (for error messages)."""
    if not isinstance(root, MappingNode):
        return {}
    return {str(k.value): k.start_mark.line + 1 for k, _ in root.value}


@dataclass(frozen=True)
class SensorGeometry:
    """The sensor's geometry as written in ``sensor.yaml`` (docs/dataset.md).

    Attributes:
        width, height: image size in px (346 x 260 for a DAVIS-346).
        px_per_mm: image scale at the gel's centre (px/mm); 2.5 means r = 30 px ~ 12 mm.
        gel_center_px: (cx, cy), the gel's centre in the image frame (px).
        gel_radius_px: radius of the gel's visible disc in the image (px).
        mirror: True when the camera sees the gel from inside (the image is mirrored).
        rotation_deg: counter-clockwise rotation from mirrored image to user frame (degrees).
        radial_k: (k1, k2), the camera model's radial terms (module docstring), or None: the
            linear mapping (one px_per_mm).
        creep: (q, tau_s), the gel's creep as a standard linear solid: the delayed share q in
            [0, 1) of its deformation and its retardation time (s), measured by ``calibrate
            --press`` (:mod:`neurotouch_hid.pipeline.creep`), or None: not measured (the
            pipeline then takes the gel as elastic).
    """

    width: int = DAVIS346_WIDTH
    height: int = DAVIS346_HEIGHT
    px_per_mm: float = 2.5
    gel_center_px: tuple[float, float] = (173.0, 130.0)
    gel_radius_px: float = 75.0
    mirror: bool = True
    rotation_deg: float = 0.0
    radial_k: tuple[float, float] | None = None
    creep: tuple[float, float] | None = None
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    # --- loading and saving -------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> "SensorGeometry":
        """Read a ``sensor.yaml`` (docs/dataset.md).

        Keys other than the docs/dataset.md ones are kept in ``extra`` (the simulator writes its
        marker layout there). Raises :class:`SensorError` naming the file and the field when
        the file is missing, is not YAML, or a field has the wrong type.
        """
        path = Path(path)
        text = read_outside_text(
            path, MAX_YAML_BYTES, "sensor file", SensorError, "expected a sensor.yaml, see docs/dataset.md"
        )
        try:
            data, root = load_yaml(text)
        except YamlError as exc:
            raise SensorError(f"{where(path, exc.line)}: not valid YAML: {exc.problem}") from None
        if not isinstance(data, dict):
            raise SensorError(
                f"{path}: expected a mapping of sensor fields (docs/dataset.md), found {type(data).__name__}"
            )
        try:
            fields = _SENSOR_FILE.validate_python({k: v for k, v in data.items() if k in SensorFile.__annotations__})
        except ValidationError as exc:
            lines = _key_lines(root)
            problems = []
            for err in exc.errors():
                key = str(err["loc"][0]) if err["loc"] else ""
                at = where(path, lines.get(key, 0))
                message = err["msg"].removeprefix("Value error, ")
                problems.append(
                    f"{at}: field {key!r}: found {short(err['input'])}; {message[:1].lower() + message[1:]}"
                )
            raise SensorError("; ".join(problems)) from None
        extra = {k: v for k, v in data.items() if k not in SensorFile.__annotations__}
        return cls(**fields, extra=extra)

    def to_dict(self) -> dict:
        """The docs/dataset.md fields (plus ``extra``) as plain YAML-able values."""
        data = asdict(self)
        extra = data.pop("extra")
        data["gel_center_px"] = [float(c) for c in self.gel_center_px]
        if self.radial_k is None:
            del data["radial_k"]  # the linear mapping: the file stays as docs/dataset.md's
        else:
            data["radial_k"] = [float(k) for k in self.radial_k]
        if self.creep is None:
            del data["creep"]
        else:
            data["creep"] = [float(c) for c in self.creep]
        data.update(extra)
        return data

    def save(self, path: str | Path) -> None:
        """Write this geometry as ``sensor.yaml`` (docs/dataset.md field order), renamed into
        place when complete. Raises OutputError for a symbolic link or a folder."""
        with AtomicFile(path, what="sensor file") as fh:
            fh.write(yaml.safe_dump(self.to_dict(), sort_keys=False))

    # --- conversions --------------------------------------------------------------------
    @property
    def gel_radius_mm(self) -> float:
        """Radius of the gel's visible disc in mm (at the centre's scale)."""
        return self.gel_radius_px / self.px_per_mm

    def rotation_matrix(self) -> np.ndarray:
        """(2, 2) float64, the user frame's rotation by ``rotation_deg`` (counter-clockwise): the
        last step of :meth:`vectors_image_to_user` (row vectors times its transpose)."""
        a = math.radians(self.rotation_deg)
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    def vectors_image_to_user(self, vectors_px: np.ndarray) -> np.ndarray:
        """Convert displacement vectors from image px to user-frame mm.

        Args:
            vectors_px: (..., 2) float, image frame (x right, y down), px.
        Returns:
            (..., 2) float64, user frame (x right, y up), mm.
        """
        v = np.asarray(vectors_px, dtype=np.float64)
        d = np.stack([v[..., 0], -v[..., 1]], axis=-1) / self.px_per_mm
        if self.mirror:
            d[..., 0] = -d[..., 0]
        if self.rotation_deg:
            d = d @ self.rotation_matrix().T
        return d

    def vectors_user_to_image(self, vectors_mm: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`vectors_image_to_user`: (..., 2) user mm -> (..., 2) image px."""
        d = np.asarray(vectors_mm, dtype=np.float64)
        if self.rotation_deg:
            d = d @ self.rotation_matrix()  # inverse rotation (orthogonal matrix)
        d = d.copy()
        if self.mirror:
            d[..., 0] = -d[..., 0]
        return np.stack([d[..., 0], -d[..., 1]], axis=-1) * self.px_per_mm

    def radial_gain(self, radius_px: np.ndarray) -> np.ndarray:
        """(...) float64, the camera model's factor ``1 + k1 x^2 + k2 x^4`` at image radii (...)
        px from the gel's centre (x = radius / gel_radius_px); 1 without a camera model."""
        x2 = (np.asarray(radius_px, dtype=np.float64) / self.gel_radius_px) ** 2
        if self.radial_k is None:
            return np.ones_like(x2)
        k1, k2 = self.radial_k
        return 1.0 + k1 * x2 + k2 * x2 * x2

    def image_to_user(self, points_px: np.ndarray) -> np.ndarray:
        """Convert points from the image frame (px) to the user frame (mm), docs/dataset.md formula
        (with the camera model, ``radial_k``, when there is one).

        Args:
            points_px: (..., 2) float, (u, v) image px.
        Returns:
            (..., 2) float64, user frame mm, origin at the gel's centre.
        """
        return self.vectors_image_to_user(self._undistorted_offsets(points_px))

    def _undistorted_offsets(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) float64: image points' offsets (px) from the gel's centre times the camera
        model's :meth:`radial_gain` (unchanged without a model)."""
        p = np.asarray(points_px, dtype=np.float64) - np.asarray(self.gel_center_px)
        if self.radial_k is not None:
            p = p * self.radial_gain(np.hypot(p[..., 0], p[..., 1]))[..., None]
        return p

    def user_to_image(self, points_mm: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`image_to_user`: (..., 2) user mm -> (..., 2) image px (the camera
        model inverted as :meth:`distort` does)."""
        return self.distort(self.vectors_user_to_image(points_mm) + np.asarray(self.gel_center_px))

    def undistort(self, points_px: np.ndarray) -> np.ndarray:
        """Image points as a camera without the camera model (``radial_k``) would see them: each
        point's offset from the gel's centre times :meth:`radial_gain`, so that one px is one
        base-plane mm / ``px_per_mm`` everywhere on the gel (the centre's scale; image frame, px).

        Args:
            points_px: (..., 2) float, image px; NaN rows stay NaN.
        Returns:
            (..., 2) float64, undistorted px; the points unchanged without a camera model.
        """
        if self.radial_k is None:
            return np.array(points_px, dtype=np.float64)
        return self._undistorted_offsets(points_px) + np.asarray(self.gel_center_px)

    def distort(self, points_px: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`undistort`: (..., 2) undistorted px -> (..., 2) image px, the camera
        model's radius ``r (1 + k1 x^2 + k2 x^4)`` solved for r by Newton's method (until a step
        is below 1e-9 px, at most 8 steps)."""
        p = np.asarray(points_px, dtype=np.float64) - np.asarray(self.gel_center_px)
        if self.radial_k is not None:
            target = np.hypot(p[..., 0], p[..., 1])  # = r g(r), solved for the image radius r
            r = target.copy()
            k1, k2 = self.radial_k
            per_x2 = 1.0 / self.gel_radius_px**2
            for _ in range(8):
                x2 = r * r * per_x2
                step = (r * (1.0 + x2 * (k1 + k2 * x2)) - target) / (1.0 + x2 * (3.0 * k1 + 5.0 * k2 * x2))
                r = r - step
                if np.fmax.reduce(np.abs(step), axis=None, initial=0.0) <= 1e-9:  # converged (NaN left aside)
                    break
            scale = np.where(target > 0, r / np.where(target > 0, target, 1.0), 1.0)
            p = p * scale[..., None]
        return p + np.asarray(self.gel_center_px)

    def rotation_image_to_user(self, angle_rad: float) -> float:
        """A rotation angle measured in the image frame (counter-clockwise as displayed, i.e.
        with y up) expressed in the user frame: the mirror flips its sign, a rotation keeps it.
        """
        return -angle_rad if self.mirror else angle_rad

    def inside_gel(self, points_px: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Boolean mask (...,) of image points (..., 2) px inside the gel circle (+ margin px)."""
        p = np.asarray(points_px, dtype=np.float64) - np.asarray(self.gel_center_px)
        return np.hypot(p[..., 0], p[..., 1]) <= self.gel_radius_px + margin_px

    def gel_mask(self, margin_px: float = 0.0) -> np.ndarray:
        """uint8 mask (height, width): 255 inside the gel circle (+ margin px), 0 outside."""
        yy, xx = np.mgrid[0 : self.height, 0 : self.width]
        inside = np.hypot(xx - self.gel_center_px[0], yy - self.gel_center_px[1]) <= self.gel_radius_px + margin_px
        return inside.astype(np.uint8) * 255


def user_sensor_path() -> Path:
    """Where ``neurotouch-hid calibrate`` saves the user's sensor.yaml by default:
    ``platformdirs.user_config_dir("neurotouch-hid")/sensor.yaml`` (``$XDG_CONFIG_HOME/neurotouch-hid``
    on Linux, beside the user's ``profiles``). The file may not exist; nothing is created here."""
    import platformdirs

    return Path(platformdirs.user_config_dir("neurotouch-hid")) / "sensor.yaml"


def default_sensor() -> SensorGeometry:
    """The geometry when nothing more specific is known (the live camera; a recording without a
    sensor.yaml beside it): the user's calibration (:func:`user_sensor_path`) if there is one,
    else the default DAVIS-346 NeuroTouch geometry of docs/dataset.md.

    Raises :class:`SensorError` naming the file when the user's sensor.yaml is invalid.
    """
    path = user_sensor_path()
    return SensorGeometry.load(path) if path.exists() else SensorGeometry()


def chosen_sensor_file(recording: str | Path, sensor: str | Path | None = None) -> Path | None:
    """The sensor.yaml :func:`find_sensor_file` reads for a recording: ``sensor``, else the one
    beside the recording, else the user's calibration; None for the built-in geometry."""
    if sensor is not None:
        return Path(sensor)
    beside = Path(recording).with_name("sensor.yaml")
    if beside.exists():
        return beside
    return user_sensor_path() if user_sensor_path().exists() else None


def find_sensor_file(recording: str | Path, sensor: str | Path | None = None) -> SensorGeometry:
    """The geometry for a recording: ``sensor`` if given, else ``sensor.yaml`` beside the
    recording, else the user's calibration, else the default geometry (:func:`default_sensor`;
    which one: :func:`chosen_sensor_file`).

    Raises :class:`SensorError` naming the file when the chosen sensor.yaml is missing or invalid.
    """
    chosen = chosen_sensor_file(recording, sensor)
    return SensorGeometry.load(chosen) if chosen is not None else SensorGeometry()
