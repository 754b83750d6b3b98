"""``python -m tactile6d.cli ...``: the ``tactile6d`` console script, for environments without it on PATH."""

import sys

from tactile6d.cli import main

sys.exit(main())
