"""``python -m datasets_gen CONFIG --out DIR [--workers N | --scheduler ADDRESS|local:N] [--seed S]``."""

import sys

from .runner import main

if __name__ == "__main__":
    sys.exit(main())
