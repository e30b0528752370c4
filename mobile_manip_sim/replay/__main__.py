from mobile_manip_sim.replay.cli import main

raise SystemExit(main())
