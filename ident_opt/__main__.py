from ident_opt.cli import main

raise SystemExit(main())
