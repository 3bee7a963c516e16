from vine_nlp.front.cli import main

raise SystemExit(main())
