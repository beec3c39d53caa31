from cell.cli import main

raise SystemExit(main())
