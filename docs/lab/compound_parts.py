"""Which of the ``compound`` family's effects costs what: ``family_eval.py`` on ``compound`` with
one effect taken out at a time (docs/lab/accuracy-history.md, "Several effects at once").

    python3 docs/lab/compound_parts.py --out DIR --sessions --seed 1 --users 5,6,7,8,9 \\
        --method "ours=default" --families compound,c-nocreep,c-noflicker,c-nonoise,c-nocamera,c-nomarkers,c-gauss

Every option is ``benchmarks/family_eval.py``'s; the families ``c-...`` exist only here, each
``compound`` with one effect back at the default family's: ``c-nocreep`` no creep, ``c-noflicker``
steady light, ``c-nonoise`` the default sensor's noise, ``c-nocamera`` the orthographic camera,
``c-nomarkers`` equal markers, ``c-gauss`` the Gaussian falloff without indentation. Figures only.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from neurotouch_hid.sources.physics import PHYSICS, Physics

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

_BASE = PHYSICS["compound"]
_DEFAULT = Physics()
PARTS = (
    replace(_BASE, name="c-nocreep", creep=_DEFAULT.creep),
    replace(_BASE, name="c-noflicker", flicker=_DEFAULT.flicker),
    replace(
        _BASE, name="c-nonoise", noise_hz=_DEFAULT.noise_hz, n_hot=_DEFAULT.n_hot, hot_rate_hz=_DEFAULT.hot_rate_hz
    ),
    replace(_BASE, name="c-nocamera", perspective=_DEFAULT.perspective, k1=_DEFAULT.k1),
    replace(_BASE, name="c-nomarkers", size_spread=_DEFAULT.size_spread, brightness_spread=_DEFAULT.brightness_spread),
    replace(_BASE, name="c-gauss", falloff=_DEFAULT.falloff, indent=_DEFAULT.indent),
)
# registered at import, so that family_eval's worker processes (which import this module) know them
for _part in PARTS:
    PHYSICS.setdefault(_part.name, _part)

import family_eval  # noqa: E402  (benchmarks/, put on the path above)

if __name__ == "__main__":
    family_eval.app()
