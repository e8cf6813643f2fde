from activetouch.service.cli import main

raise SystemExit(main())
