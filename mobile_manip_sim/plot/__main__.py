from mobile_manip_sim.plot.cli import main

raise SystemExit(main())
