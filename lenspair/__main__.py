"""Entry point for ``python -m lenspair``."""

import sys

from lenspair.cli import main

sys.exit(main())
