"""The numbers a figure shows, as JSON beside its PNG (`fig.png` -> `fig.json`).

docs/ embeds figures and states their numbers in its text; the sidecar is what a test reads to check that
text against the run that drew the figure, without re-running hours of real-time or saturation runs
(tests/test_doc_figures.py).  Floats are rounded to 6 decimals so that a sidecar is byte for byte the same
for the same run, and readable in a diff.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def _rounded(x: Any) -> Any:
    if isinstance(x, float):
        return round(x, 6) if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _rounded(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_rounded(v) for v in x]
    return x


def path_of(png: Path) -> Path:
    return png.with_suffix(".json")


def write(png: Path, numbers: dict[str, Any]) -> Path:
    """Write `numbers` beside `png`; returns the sidecar's path."""
    p = path_of(png)
    p.write_text(json.dumps(_rounded(numbers), indent=1, sort_keys=True, allow_nan=False) + "\n", encoding="utf-8")
    return p


def read(png: Path) -> dict[str, Any]:
    """The numbers beside `png` ({} when there is no sidecar)."""
    p = path_of(png)
    return json.loads(p.read_text(encoding="utf-8")) if p.exists() else {}
