"""The adapted model: what ``neurotouch-hid adapt`` fitted to one gel and hand, as a small YAML
file (docs/method.md, "Adaptation"), and how it is applied to the pipeline's settings.

The file holds only what differs from the shipped method::

    format: neurotouch-hid model
    version: 1
    settings:                         # PipelineConfig fields, GROUP.FIELD: value (ADAPTABLE)
      gesture.intensity_gain: 1.04
    classifier:                       # the learned type, refitted (pipeline/learned.py)
      mean: [9 values]
      scale: [9 values]
      weights: [5 rows of 9 values]
      intercept: [5 values]
    fitted: {...}                     # what it was fitted from and its held-out check (not read)

Applying it (:func:`apply_model`) changes values of
:class:`~neurotouch_hid.pipeline.config.PipelineConfig`, never the pipeline's structure; the
paper's method (``--method paper``) is left as it is. The user's model lives in
``platformdirs.user_config_dir("neurotouch-hid")/model.yaml`` (:func:`user_model_path`, beside
sensor.yaml); ``--model PATH`` picks another, ``--model none`` the shipped method
(:func:`resolve_model`). Read through the bounded reader (``limits.py``); written with a temporary
file and a rename.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.limits import YamlError, load_yaml, read_outside_text, short, where

#: The format's name (the file's ``format``) and the version this code reads and writes.
FORMAT = "neurotouch-hid model"
VERSION = 1
#: Largest model file read (bytes): a model is ~2 KB.
MAX_MODEL_BYTES = 64 * 1024
#: The settings a model may change (``GROUP.FIELD`` of PipelineConfig), each a number.
ADAPTABLE = (
    "gesture.min_intensity_mm",
    "gesture.intensity_gain",
    "resting.centroid_threshold_mm2",
    "resting.centroid_reset_threshold_mm2",
    "episode.first_finger_us",
)
#: ``--model none``: the shipped method.
NONE = "none"
#: The range of each setting a model may hold (inclusive; the field's units), what a gel can be:
#: a contact threshold from 0 to 5 mm (gestures reach 2-10 mm); an intensity scale from 0.2 to 5
#: (another gel of the same make is within a few tens of percent; 999 is labels in micrometres);
#: resting thresholds up to 1 mm^2 per marker (1 mm of every marker is a pressed gel); a wait for
#: the second finger of at most 1 s.
SETTING_RANGES: dict[str, tuple[float, float]] = {
    "gesture.min_intensity_mm": (0.0, 5.0),
    "gesture.intensity_gain": (0.2, 5.0),
    "resting.centroid_threshold_mm2": (0.0, 1.0),
    "resting.centroid_reset_threshold_mm2": (0.0, 1.0),
    "episode.first_finger_us": (0.0, 1_000_000.0),
}
#: The range of the learned type's numbers (``pipeline/learned.py``): the features' means (shares
#: in [-1, 1], a contact count up to 3, the log of an intensity in px up to log 4096) and scales,
#: and the weights and intercepts over standardised features (the shipped ones are under 3; 100
#: already turns a twentieth of a standard deviation into a factor e^5 of odds).
CLASSIFIER_RANGES: dict[str, tuple[float, float]] = {
    "mean": (-10.0, 10.0),
    "scale": (1e-3, 10.0),
    "weights": (-100.0, 100.0),
    "intercept": (-100.0, 100.0),
}


def out_of_range(key: str, value: float, ranges: dict[str, tuple[float, float]] = SETTING_RANGES) -> str | None:
    """What is wrong with ``value`` for ``key`` (``expected LOW to HIGH``), or None when it is in
    :data:`SETTING_RANGES` (or ``ranges``)."""
    low, high = ranges[key]
    return None if low <= value <= high else f"a number from {low:g} to {high:g}"


class ModelError(NeurotouchError):
    """A model file is missing, unreadable or invalid (names the file, the field, what was found
    and what was expected)."""


@dataclass(frozen=True)
class Model:
    """An adapted model (module docstring).

    Attributes:
        settings: ``GROUP.FIELD`` (one of :data:`ADAPTABLE`) -> value, in the field's units (mm,
            mm^2 per marker, us, a factor).
        classifier: the refitted learned type as ``{"mean", "scale", "weights", "intercept"}``
            lists (shapes (9,), (9,), (5, 9), (5,)), or None: the shipped one.
        fitted: what it was fitted from and its held-out check (free-form, written for people).
        path: the file it was read from (None when made in memory).
    """

    settings: dict[str, float] = field(default_factory=dict)
    classifier: dict[str, Any] | None = None
    fitted: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def changes(self) -> list[str]:
        """What the model changes from the shipped method, one phrase each."""
        out = [f"{k} = {v:g}" for k, v in self.settings.items()]
        if self.classifier is not None:
            out.append("the learned gesture type refitted")
        return out

    def to_yaml(self) -> str:
        """The file's text (module docstring's format)."""
        import yaml

        data: dict[str, Any] = {"format": FORMAT, "version": VERSION}
        if self.settings:
            data["settings"] = {k: float(f"{v:.6g}") for k, v in self.settings.items()}
        if self.classifier is not None:
            data["classifier"] = {
                k: [[float(x) for x in row] for row in v] if k == "weights" else [float(x) for x in v]
                for k, v in self.classifier.items()
            }
        if self.fitted:
            data["fitted"] = self.fitted
        head = "# neurotouch-hid adapt: the recogniser fitted to one gel and hand (docs/method.md, Adaptation)\n"
        return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=1 << 16)

    def save(self, path: str | Path) -> Path:
        """Write the model to ``path`` through a temporary file in the same folder and a rename
        (a reader never sees half a file; an interrupted write leaves the old one); ``-`` is
        standard output, a FIFO or a character device is written as it is
        (``atomic.AtomicFile``). Creates the folder.

        Raises:
            OutputError: ``path`` is a symbolic link or a folder, or the disk refuses the write.
            ModelError: it cannot be written otherwise.
        """
        from neurotouch_hid.core.atomic import AtomicFile

        path = Path(path)
        if str(path) == "-":
            sys.stdout.write(self.to_yaml())
            sys.stdout.flush()
            return path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with AtomicFile(path, what="model") as fh:
                fh.write(self.to_yaml())
        except OSError as exc:
            raise ModelError(f"{path}: cannot write the model: {exc.strerror or exc}") from None
        return path


def user_model_path() -> Path:
    """The user's model: ``platformdirs.user_config_dir("neurotouch-hid")/model.yaml`` (beside
    sensor.yaml). The file may not exist; nothing is created here."""
    import platformdirs

    return Path(platformdirs.user_config_dir("neurotouch-hid")) / "model.yaml"


def reset_user_model() -> str:
    """Go back to the shipped method: the user's model (:func:`user_model_path`) is renamed
    ``model.yaml.bak`` (an older backup replaced), so nothing is lost and renaming it back
    restores it. Returns what was done, one line for people.

    Raises:
        ModelError: the file cannot be renamed (its folder's permissions).
    """
    path = user_model_path()
    if not path.exists():
        return f"no adapted model ({path} does not exist): the shipped recogniser is already in use"
    backup = path.with_name(path.name + ".bak")
    try:
        os.replace(path, backup)
    except OSError as exc:
        raise ModelError(f"{path}: cannot move it aside: {exc.strerror or exc}") from None
    return (
        f"the shipped recogniser is in use again; your adapted model is kept as {backup} "
        f"(rename it back to {path.name} to use it again)"
    )


def _lines(root: Any, prefix: str = "") -> dict[str, int]:
    """The 1-based line of every key of a YAML mapping node, nested keys as ``a.b``."""
    from ruamel.yaml.nodes import MappingNode

    out: dict[str, int] = {}
    if isinstance(root, MappingNode):
        for k, v in root.value:
            name = f"{prefix}{k.value}"
            out[name] = k.start_mark.line + 1
            out.update(_lines(v, name + "."))
    return out


def load_model(path: str | Path) -> Model:
    """Read a model file (module docstring's format).

    Raises:
        ModelError: the file is missing, not a regular file or too large (``limits.py``), not
            UTF-8 YAML, of another format or an unknown version (the message says what to do),
            or a field is unknown, missing or of the wrong shape (``FILE:LINE: field NAME: found
            VALUE; expected ...``).
    """
    from pydantic import ValidationError

    from neurotouch_hid.pipeline.config import ClassifierConfig

    path = Path(path)
    text = read_outside_text(
        path, MAX_MODEL_BYTES, "model file", ModelError, "write one with `neurotouch-hid adapt`, or use --model none"
    )
    try:
        data, root = load_yaml(text)
    except YamlError as exc:
        raise ModelError(f"{where(path, exc.line)}: not valid YAML: {exc.problem}") from None
    lines = _lines(root)

    def bad(key: str, found: Any, expected: str) -> ModelError:
        return ModelError(f"{where(path, lines.get(key, 0))}: field {key!r}: found {short(found)}; expected {expected}")

    if not isinstance(data, dict):
        raise ModelError(f"{path}: expected a mapping (a model written by `neurotouch-hid adapt`), found {short(data)}")
    if data.get("format") != FORMAT:
        raise bad("format", data.get("format"), f"{FORMAT!r} (is this a model written by `neurotouch-hid adapt`?)")
    version = data.get("version")
    if isinstance(version, bool) or version != VERSION:  # ``true`` is no version (True == 1 in Python)
        raise ModelError(
            f"{where(path, lines.get('version', 0))}: model format version {short(version)} is not one this "
            f"neurotouch-hid reads (it reads version {VERSION}): run `neurotouch-hid adapt` again to write one, "
            "or use --model none for the shipped method"
        )
    unknown = sorted(set(data) - {"format", "version", "settings", "classifier", "fitted"})
    if unknown:
        raise bad(unknown[0], data[unknown[0]], "only format, version, settings, classifier, fitted")
    settings = data.get("settings") or {}
    if not isinstance(settings, dict):
        raise bad("settings", settings, f"a mapping of GROUP.FIELD: number ({', '.join(ADAPTABLE)})")
    out: dict[str, float] = {}
    for key, value in settings.items():
        if key not in ADAPTABLE:
            raise bad(f"settings.{key}", key, f"one of {', '.join(ADAPTABLE)}")
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or value != value
            or abs(value) == float("inf")
        ):
            raise bad(f"settings.{key}", value, "a finite number")
        expected = out_of_range(key, float(value))
        if expected is not None:
            raise bad(f"settings.{key}", value, f"{expected} (docs/limits.md, Models)")
        out[key] = float(value)
    classifier = data.get("classifier")
    if classifier is not None:
        if not isinstance(classifier, dict):
            raise bad("classifier", classifier, "a mapping of mean, scale, weights, intercept")
        try:
            ClassifierConfig.model_validate(classifier)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in err["loc"][:1])
            key = f"classifier.{loc}" if loc else "classifier"
            message = err["msg"].removeprefix("Value error, ")
            raise bad(key, err["input"], message[:1].lower() + message[1:]) from None
        for part, values in classifier.items():
            flat = [x for row in values for x in row] if part == "weights" else list(values)
            wrong = next((x for x in flat if out_of_range(part, float(x), CLASSIFIER_RANGES)), None)
            if wrong is not None:
                expected = out_of_range(part, float(wrong), CLASSIFIER_RANGES)
                raise bad(f"classifier.{part}", wrong, f"{expected} (docs/limits.md, Models)")
    fitted = data.get("fitted") or {}
    if not isinstance(fitted, dict):
        raise bad("fitted", fitted, "a mapping")
    model = Model(out, classifier, fitted, path)
    apply_model(None, model)  # the values together must make valid settings
    return model


def apply_model(config, model: Model | None, keep: Sequence[str] = ()):
    """``config`` (a :class:`~neurotouch_hid.pipeline.config.PipelineConfig`; None: the shipped
    one) with ``model``'s values, but for the ``GROUP.FIELD`` names in ``keep`` (given on the
    command line: ``--set`` wins); the paper's settings (:class:`~neurotouch_hid.pipeline.paper.PaperConfig`)
    and ``model`` None are returned as they are. The pipeline's structure is unchanged: only values
    of its settings (``gesture.classifier`` among them).

    Raises:
        ModelError: the model's values are not valid settings together (names the file and field).
    """
    from pydantic import ValidationError

    from neurotouch_hid.pipeline.config import PipelineConfig

    if model is None or (config is not None and not isinstance(config, PipelineConfig)):
        return config
    data = (config or PipelineConfig()).model_dump()
    for key, value in model.settings.items():
        if key not in keep:
            group, name = key.split(".")
            data[group][name] = value
    if model.classifier is not None and "gesture.classifier" not in keep:
        data["gesture"]["classifier"] = model.classifier
    try:
        return PipelineConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        message = err["msg"].removeprefix("Value error, ")
        source = model.path or "the model"
        raise ModelError(f"{source}: {'.'.join(str(p) for p in err['loc'])}: {message}") from None


def resolve_model(option: str | None) -> Model | None:
    """The model a command uses: ``--model`` as given (``none``: the shipped method, None; a
    path: that file) or, without the option, the user's (:func:`user_model_path`) when it exists.

    Raises:
        ModelError: the chosen file is missing or invalid.
    """
    if option is not None and option.strip().lower() == NONE:
        return None
    if option is not None:
        return load_model(Path(option).expanduser())
    path = user_model_path()
    return load_model(path) if path.exists() else None


def fitted_on(model: Model | None, dataset: str | Path) -> bool:
    """True when ``model`` was fitted on ``dataset`` (its ``fitted.from`` names that folder, by
    device and inode however it is spelled; a relative name as the folder it names from here)."""
    if model is None:
        return False
    sources = model.fitted.get("from") if isinstance(model.fitted, dict) else None
    for source in sources if isinstance(sources, list) else []:
        try:
            if os.path.samefile(str(source), dataset):
                return True
        except (OSError, TypeError, ValueError):
            continue
    return False


def describe(model: Model | None) -> str:
    """One line for people: which model is in use and what it changes."""
    if model is None:
        return "the shipped method (no adapted model)"
    changes = model.changes()
    return (
        f"{model.path or 'an adapted model'} ({'; '.join(changes) if changes else 'no change from the shipped method'})"
    )
