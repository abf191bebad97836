from hbeo.cli import main

raise SystemExit(main())
