from legs_jax.online.cli import main

raise SystemExit(main())
