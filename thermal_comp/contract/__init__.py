"""The contract between host, codegen, hil and the firmware: one home for each fact.

Ground floor: imports nothing of the project and no third-party package (stdlib only), so the
LinuxCNC component on Debian's /usr/bin/python3 can use it too.
- ``contract.fixed_point``: widths, rounding and alpha quantisation (docs/fixed-point.md);
- ``contract.terms``: the term kinds and the ``Term`` of a model;
- ``contract.box``: capacities of the box and of its model runtime;
- ``contract.model_file``: the one reader/validator/writer of model.json (docs/model-json.md);
- ``contract.protocol``: the serial wire protocol and the status word (docs/protocol.md).
tests/contract/test_contract.py parses the firmware headers and checks them against these modules.
"""

from __future__ import annotations

__version__ = "0.1.0"  # tool version: model.json's tool_version, the box's BOX_FW_VERSION
