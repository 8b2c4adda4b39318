from bywire.cli import main

raise SystemExit(main())
