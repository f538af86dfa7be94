"""`python -m thermal_comp.cnc` (= `make cnc`): the box through a headless LinuxCNC
(cnc/session.py)."""

import sys

from thermal_comp.cnc.session import main

sys.exit(main())
