"""`python -m phc.cli` runs the command line (as `python -m phc` does, without its thread settings)."""

import sys

from phc.cli import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
