"""Why a model file is refused: its own error classes, apart from the rules that raise them.

The host CLI turns them (``InputError``s) into a message and exit code 2; a stale hash has its
own class so a caller can tell an edited model from a malformed one.
"""

from __future__ import annotations

from thermal_comp.contract.errors import InputError


class ModelFormatError(InputError):
    """A model file is missing, not JSON, or breaks the schema; the message names where."""


class ModelHashError(ModelFormatError):
    """A model's content no longer matches the hash stored with it (edited or corrupted)."""
