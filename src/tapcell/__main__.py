from tapcell.cli import main

raise SystemExit(main())
