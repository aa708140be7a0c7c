"""``python -m network_sim`` is ``network-sim``."""

from network_sim import main

main()
