from tapcell.tools.cli import main

raise SystemExit(main())
