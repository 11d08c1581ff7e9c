"""`python -m global_loc`: the command line (see cli.py)."""
import sys

from .offline.cli import main

sys.exit(main())
