"""The tests mirror the project's layers (tests/<package>/...); their shared helpers
(firmware_support, fleet_support, direct_fits) stay here, importable from every folder."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
