"""The model hash: identifies the function a model computes, not how it was found.

Defined in ``contract.model_file`` (every reader of a model checks the stored hash there);
re-exported here for codegen's callers.
"""

from __future__ import annotations

from thermal_comp.contract.model_file import model_hash

__all__ = ["model_hash"]
