from activetouch.cli.main import main

raise SystemExit(main())
