"""Run as `python -m capsd`."""

import sys

from capsd.cli import main

sys.exit(main())
