"""``python -m baseline_cloudbaking.server``: the same as ``cloudbaking-server``."""

import sys

from baseline_cloudbaking.server import main

sys.argv[0] = "cloudbaking-server"  # usage and error lines name the command as the console script does
main()
