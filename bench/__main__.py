import sys

from bench.cli import main

sys.argv[0] = "bench"  # usage and error lines name the command as the console script does
main()
