"""`python -m phc` runs the command line."""

import sys

from phc.cli import main

sys.exit(main())
