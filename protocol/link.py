"""The link: flow-control credits and the codec's parameters.

# Ref: ECSS-E-ST-50-12C §8.5 (flow control), §6.6 (signalling rate), §8.5.2 (link timing).

Shared by the link's gateware (:mod:`mrm_cosim.hdl.link`) and its cycle-level reference
(:class:`~mrm_cosim.hdl.link.codec_ref.CodecRef`), which must accept and refuse exactly the
same parameters.
"""

__all__ = ["FCT_CREDIT", "MAX_CREDIT", "MAX_SLOTS", "check_slots", "check_div", "check_cycles",
           "codec_params"]

#: Flow control: one FCT grants 8 N-chars; at most 56 may be outstanding (§8.5 / flow control).
FCT_CREDIT = 8
MAX_CREDIT = 56

#: Widest SERDES supported: with at most 4 slots a cycle holds at most one character boundary,
#: which the character receiver and the transmitter's refill rule rely on.
MAX_SLOTS = 4


def _is_int(value):
    return isinstance(value, int) and not isinstance(value, bool)


def check_slots(slots):
    if not _is_int(slots) or not 1 <= slots <= MAX_SLOTS:
        raise ValueError(f"Slots per cycle must be an integer from 1 to {MAX_SLOTS}, "
                         f"not {slots!r}")


def check_div(div, name):
    if not _is_int(div) or div < 1:
        raise ValueError(f"{name} must be a positive integer number of slots, not {div!r}")


def check_cycles(cycles, name, minimum=1):
    if not _is_int(cycles) or cycles < minimum:
        raise ValueError(f"{name} must be an integer number of cycles of at least {minimum}, "
                         f"not {cycles!r}")


def codec_params(*, slots=3, start_div=None, run_div=1, reset_cycles=320, wait_cycles=640,
                 disconnect_cycles=43, rx_fifo_depth=64):
    """Check the codec's parameters; return them with ``start_div`` resolved (10 Mbit/s)."""
    check_slots(slots)
    if start_div is None:
        start_div = 5 * slots
    check_div(start_div, "Start bit period")
    check_div(run_div, "Run bit period")
    check_cycles(disconnect_cycles, "Disconnect time", 3)
    check_cycles(wait_cycles, "Wait time")
    # Exchange of silence: the peer must have detected our silence and fallen silent itself
    # before our receiver comes out of Error-Reset.
    check_cycles(reset_cycles, "Reset time (disconnect time + 5)", disconnect_cycles + 5)
    if not _is_int(rx_fifo_depth) or rx_fifo_depth < FCT_CREDIT + 1:
        raise ValueError(f"Receive FIFO depth must be an integer of at least "
                         f"{FCT_CREDIT + 1}, not {rx_fifo_depth!r}")
    return dict(slots=slots, start_div=start_div, run_div=run_div, reset_cycles=reset_cycles,
                wait_cycles=wait_cycles, disconnect_cycles=disconnect_cycles,
                rx_fifo_depth=rx_fifo_depth)
