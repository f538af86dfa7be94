"""The model hash: identifies the function a model computes, not how it was found."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping


def model_hash(model: Mapping) -> str:
    """First 16 hex digits of SHA-256 over the canonical JSON of the model's function.

    Canonical = sorted keys, no spaces, of ``{sample_period_s, channels, aux, time_max_s,
    axes: {name: {unit, intercept, terms}}}`` (docs/model-json.md); metrics, selection
    traces and the ``fixed_point`` block do not change it. A missing optional key hashes as
    ``null`` (``aux`` as ``[]``).
    """
    core = {
        "sample_period_s": model.get("sample_period_s"),
        "channels": model.get("channels", []),
        "aux": model.get("aux", []),
        "time_max_s": model.get("time_max_s"),
        "axes": {
            name: {"unit": ax.get("unit"), "intercept": ax.get("intercept"),
                   "terms": ax.get("terms", [])}
            for name, ax in model.get("axes", {}).items()
        },
    }
    text = json.dumps(core, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
