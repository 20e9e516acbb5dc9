from rosdeploy.cli import main

raise SystemExit(main())
