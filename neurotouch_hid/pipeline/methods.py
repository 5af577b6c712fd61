"""The pipeline's methods by name (``track``/``eval``/``run --method NAME``): each a config model
and the pipeline that runs it, both satisfying the same seams
(:class:`~neurotouch_hid.core.stages.Pipeline`).

``default`` is the product (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`,
docs/method.md, "Overview"); ``paper`` the paper's method exactly
(:class:`~neurotouch_hid.pipeline.paper.PaperPipeline`, docs/method.md, "The paper's method").
"""

from __future__ import annotations

from neurotouch_hid.core.kinds import MethodKind
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.config import PipelineConfig
from neurotouch_hid.pipeline.paper import PaperConfig, PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline

#: Method name -> (its config model, its pipeline class).
METHODS: dict[str, tuple[type[PipelineConfig] | type[PaperConfig], type[GesturePipeline]]] = {
    MethodKind.DEFAULT: (PipelineConfig, GesturePipeline),
    MethodKind.PAPER: (PaperConfig, PaperPipeline),
}

#: Any method's settings.
MethodConfig = PipelineConfig | PaperConfig


def method_of(config: MethodConfig | None) -> str:
    """The name of the method whose settings ``config`` are (None: ``default``)."""
    return "paper" if isinstance(config, PaperConfig) else "default"


def pipeline_for(sensor: SensorGeometry, config: MethodConfig | None = None, **kwargs) -> GesturePipeline:
    """The pipeline of ``config``'s method (``GesturePipeline`` keywords: ``on_window``,
    ``profile``, ``detect_resting``)."""
    return METHODS[method_of(config)][1](sensor, config, **kwargs)
