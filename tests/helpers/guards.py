"""How long a test waits for a process before it calls it hung: a guard against a hang, not a bound on speed
(ten times what a busy 2-core machine needs for the slowest command it guards)."""

#: Seconds a test lets one command-line run take before failing it as hung.
HANG_GUARD_S = 600
