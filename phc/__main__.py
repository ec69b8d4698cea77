"""`python -m phc` runs the command line."""

import sys

from phc._entry import main

sys.exit(main())
