"""``python -m nbv_prob_cnn`` runs the ``nbv`` command line."""

from nbv_prob_cnn.cli import main

raise SystemExit(main())
