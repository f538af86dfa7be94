"""Turns a fitted model.json into a fixed-point C header (see docs/fixed-point.md).

Two stages: ``codegen.quantise`` validates the model and decides every integer (shift,
coefficients, ranges) exactly; ``codegen.render`` formats them through jinja2 templates.
``codegen.bound`` proves the error bound, ``codegen.crc`` serialises the tables and
``codegen.fixed`` is the integer twin of the C runtime used as the expectation in tests.
"""

from thermal_comp.codegen.errors import BoundError, CodegenError
from thermal_comp.codegen.generate import (
    CODEGEN_VERSION,
    DEFAULT_MAX_ERROR_UM,
    GeneratedHeader,
    export_to_c,
    fixed_point_path,
    generate,
    load_model,
    write_header,
)
from thermal_comp.codegen.hashing import model_hash

__version__ = CODEGEN_VERSION

__all__ = ["BoundError", "CODEGEN_VERSION", "DEFAULT_MAX_ERROR_UM", "CodegenError",
           "GeneratedHeader", "export_to_c", "fixed_point_path", "generate", "load_model",
           "model_hash", "write_header"]
