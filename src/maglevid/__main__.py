"""``python -m maglevid`` runs the command-line tool."""

import sys

from maglevid.cli.main import main

sys.exit(main())
