from thermal_comp.host.cli import main

raise SystemExit(main())
