"""Units every room shares: the one definition of the nodes' clock."""

CLOCK_HZ = 50_000_000
"""The slave nodes' system clock (Hz): every cycle count in the project is of this clock."""

CYCLE_S = 1.0 / CLOCK_HZ
"""One clock cycle in seconds (20 ns)."""
