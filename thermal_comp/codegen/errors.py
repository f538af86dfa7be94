"""The one exception codegen raises for a model it cannot turn into a safe header."""

from __future__ import annotations

from thermal_comp.contract.errors import InputError


class CodegenError(InputError):
    """The model cannot be generated; the message names the axis, term, value and limit.

    A ValueError so that ``host`` maps it to exit code 2 like every other bad input.
    """


class BoundError(CodegenError):
    """The proven worst-case error exceeds the --max-error-um limit: a failed check (``host
    codegen`` exits 1), not malformed input."""
