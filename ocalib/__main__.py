from ocalib.cli import main

raise SystemExit(main())
