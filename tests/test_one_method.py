"""One method per composition: the product's settings hold no experiment switch, few places branch
on a setting, and a stage built directly runs the product's method (docs/method.md, "Overview";
the paper's values belong to pipeline/paper.py).

A switch is a setting that turns a step on or off: a bool, or a number whose None means "off".
The product's settings (PipelineConfig and its groups) may keep only product choices, each named
in ``CHOICES`` with what its None means; the code may branch on them at most ``MAX_SWITCH_SITES``
times (``if`` statements and conditional expressions, found by an ``ast`` scan of the package).
"""

from __future__ import annotations

import ast
import types
import typing
from pathlib import Path

import numpy as np
from pydantic import BaseModel

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.config import PipelineConfig
from neurotouch_hid.pipeline.paper import PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.pipeline.resting import RestingDetector
from neurotouch_hid.pipeline.tracker import BlobTracker
from neurotouch_hid.sources import Frame

PACKAGE = Path(__file__).resolve().parent.parent / "neurotouch_hid"
#: Optional settings that are product choices, and what their None means (none of them "off" for
#: a step the product runs).
CHOICES = {
    "noise.kind": "no noise filter: the live camera's source filters, eval measures without",
    "noise.time_us": "the filter kind's own time (noise.NOISE_FILTERS)",
    "resting.marker_threshold": "Otsu's threshold on the rest frame",
}
MAX_SWITCH_SITES = 4


def _leaves(model: type[BaseModel], prefix: str = "") -> dict[str, object]:
    """``group.field`` -> annotation, for every non-group field of ``model`` and its groups."""
    out = {}
    for name, info in model.model_fields.items():
        annotation = info.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            out.update(_leaves(annotation, f"{prefix}{name}."))
        else:
            out[f"{prefix}{name}"] = annotation
    return out


def _optional(annotation) -> bool:
    return typing.get_origin(annotation) in (typing.Union, types.UnionType) and type(None) in typing.get_args(
        annotation
    )


def _mentions_bool(annotation) -> bool:
    return annotation is bool or any(_mentions_bool(a) for a in typing.get_args(annotation))


def test_the_product_settings_have_no_bool_and_no_none_but_product_choices():
    leaves = _leaves(PipelineConfig)
    assert "contacts.r_mm" in leaves and "tracker.assoc_mm" in leaves  # the walk reaches the groups
    bools = [name for name, annotation in leaves.items() if _mentions_bool(annotation)]
    optional = {name for name, annotation in leaves.items() if _optional(annotation)}
    assert bools == []
    assert optional == set(CHOICES), f"an optional setting that is no product choice: {optional - set(CHOICES)}"


def _reads_a_choice(dotted: str) -> bool:
    """Whether an attribute read (``ast.unparse`` text) is one of ``CHOICES``: ``noise.kind`` off
    any object, or a resting setting by its own name (the pixel settings hold those flat)."""
    parts = dotted.split(".")
    return any(
        parts[-2:] == key.split(".") or (key.startswith("resting.") and parts[-1] == key.split(".")[1])
        for key in CHOICES
    )


def _switch_sites() -> list[str]:
    """Every ``if``, ``while`` or conditional expression in the package whose test reads one of
    the optional settings through the settings (a stage's own argument is no setting)."""
    sites = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.If, ast.IfExp, ast.While)) and any(
                isinstance(n, ast.Attribute) and _reads_a_choice(ast.unparse(n)) for n in ast.walk(node.test)
            ):
                sites.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    return sites


def test_few_places_branch_on_a_setting():
    sites = _switch_sites()
    assert any(site.startswith("pipeline/pipeline.py:") for site in sites)  # the scan sees the noise filter's
    assert len(sites) <= MAX_SWITCH_SITES, sites


def _rest_frame(sensor: SensorGeometry) -> np.ndarray:
    """Gaussian markers (sigma 1.2 px) on the 4 mm grid inside the gel disc."""
    yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width].astype(np.float64)
    img = np.full(xx.shape, 20.0)
    cx, cy = sensor.gel_center_px
    pitch = 4.0 * sensor.px_per_mm
    for j in range(-7, 8):
        for i in range(-7, 8):
            x, y = cx + i * pitch, cy + j * pitch
            if np.hypot(x - cx, y - cy) <= sensor.gel_radius_px - 8:
                img += 200.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.2**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def _started(pipeline: GesturePipeline) -> GesturePipeline:
    pipeline.process(Frame(0, _rest_frame(pipeline.sensor)))
    assert pipeline.rest_px is not None and pipeline.resting_detector is not None
    return pipeline


def test_a_stage_built_directly_runs_the_products_method():
    """The resting detector and the tracker, built with the sensor alone, are the product
    pipeline's: the same Chamfer distance (over centroids, per marker) and threshold, the same
    tracker gates in pixels; the paper's pipeline builds its own."""
    sensor = SensorGeometry()
    product = _started(GesturePipeline(sensor))
    image = _rest_frame(product.sensor)
    direct = RestingDetector(image, product.sensor)
    ours = product.resting_detector
    assert (direct.threshold, direct.per_marker, direct.centroids) == (ours.threshold, ours.per_marker, ours.centroids)
    assert BlobTracker(product.rest_px, sensor=product.sensor).pixels == product.tracker.pixels

    paper = _started(PaperPipeline(sensor)).resting_detector
    assert (paper.threshold, paper.per_marker, paper.centroids) == (2.5, False, False)
    moved = np.roll(image, 2, axis=1)  # every marker 2 px (0.8 mm) to the right
    assert not direct.update(moved).resting and direct.update(image).resting
