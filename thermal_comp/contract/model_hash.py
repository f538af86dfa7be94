"""The model hash: which content of a model.json is its function, fingerprinted.

A model edited after ``host train`` wrote it must be refused, naming both hashes; metrics and
explanations must not change the hash, or every report would stale the model.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping

from thermal_comp.contract.model_errors import ModelHashError
from thermal_comp.contract.service import SERVICE_FIELDS


def _service_core(block: object) -> object:
    """The fields of an axis's ``service`` block that change the box (not its ``why``)."""
    if not isinstance(block, Mapping):
        return block
    return {k: block[k] for k in SERVICE_FIELDS if k in block}


def model_hash(model: Mapping) -> str:
    """First 16 hex digits of SHA-256 over the canonical JSON of the model's function.

    Canonical = sorted keys, no spaces, of ``{sample_period_s, channels, aux, time_max_s,
    axes: {name: {unit, intercept, terms[, max_step_um]}}}`` (docs/model-json.md); metrics,
    selection traces, the stored ``model_hash`` and the ``fixed_point`` block do not change it.
    A missing optional key hashes as ``null`` (``aux`` as ``[]``; ``max_step_um``, the box's
    output step limit, is left out when absent so that older models keep their hash). The
    top-level ``reference`` (what zero means; a ``start`` model's box zeroes at power-up) is
    part of the function too, and likewise left out when absent. So is an axis's ``service``
    block (issue 42: its parameters are in the header and decide what the box does with a
    probe reading), its numeric fields only (``why`` is an explanation), left out when absent.
    """
    core = {
        "sample_period_s": model.get("sample_period_s"),
        "channels": model.get("channels", []),
        "aux": model.get("aux", []),
        "time_max_s": model.get("time_max_s"),
        "axes": {
            name: {"unit": ax.get("unit"), "intercept": ax.get("intercept"),
                   "terms": ax.get("terms", []),
                   **({"max_step_um": ax["max_step_um"]} if "max_step_um" in ax else {}),
                   **({"service": _service_core(ax["service"])} if "service" in ax else {})}
            for name, ax in model.get("axes", {}).items()
        },
    }
    if "reference" in model:
        core["reference"] = model["reference"]
    text = json.dumps(core, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def stored_hashes(model: Mapping) -> dict[str, str]:
    """The hashes a model carries, by key: ``model_hash`` and ``fixed_point.model_hash``."""
    out = {}
    if "model_hash" in model:
        out["model_hash"] = model["model_hash"]
    fp = model.get("fixed_point")
    if isinstance(fp, Mapping) and "model_hash" in fp:
        out["fixed_point.model_hash"] = fp["model_hash"]
    return out


def check_model_hash(model: Mapping, where: str = "model") -> str:
    """The model's hash; ModelHashError when a stored hash differs from the content's."""
    actual = model_hash(model)
    for key, stored in stored_hashes(model).items():
        if stored != actual:
            raise ModelHashError(
                f"{where}: {key}: the stored hash {stored!r} does not match the model's content "
                f"(hash {actual!r}): its coefficients, terms, channels or ranges were changed "
                "after it was written. Train it again; if the edit is deliberate, delete "
                "'model_hash' and the 'fixed_point' block (docs/model-json.md)")
    return actual
