from wavebrdf.jobs.cli import main

raise SystemExit(main())
