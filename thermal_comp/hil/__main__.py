from thermal_comp.hil.cli import main

raise SystemExit(main())
