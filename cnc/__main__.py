"""`python -m cnc` (= `make cnc`): the box through a headless LinuxCNC, see cnc/session.py."""

import sys

from cnc.session import main

sys.exit(main())
