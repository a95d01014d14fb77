"""``python -m warp_sph.io.check_usd FILE [--min-frames N] [--json] [--strict]``."""
import sys

from . import main

sys.argv[0] = "check_usd.py"  # the usage line names the validator, as the one-file module did
sys.exit(main())
