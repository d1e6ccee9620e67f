from gyrolab.cli import main

raise SystemExit(main())
