"""Link state machine with its timers and per-class error counters.

# Ref: ECSS-E-ST-50-12C §8.5.2 (states Error-Reset, Error-Wait, Ready, Started, Connecting,
#      Run and their transitions), §8.5.3 (conditions: LinkEnabled, timeouts, errors).

Transitions (any of the listed conditions; an error always wins over a forward move):

=============  ======================================================  ========================
state          to Error-Reset                                          forward
=============  ======================================================  ========================
Error-Reset    --                                                      Error-Wait after 6.4 µs
Error-Wait     disconnect, parity, escape; gotFCT, gotN-Char,          Ready after 12.8 µs
               gotTime-Code
Ready          as Error-Wait                                           Started when LinkEnabled
Started        as Error-Wait; 12.8 µs without gotNULL                  Connecting on gotNULL
Connecting     disconnect, parity, escape; gotN-Char, gotTime-Code;    Run on gotFCT
               12.8 µs without gotFCT
Run            disconnect, parity, escape, credit, credit timeout;     --
               LinkDisabled
=============  ======================================================  ========================

LinkEnabled = not link_disable and (link_start or (auto_start and gotNULL)), and here also
``fct_room``: the receive buffer can take the first 8 N-chars, so the FCT that Connecting
needs can be sent (as SpaceWire Light does). Every timer is counted in clock cycles from the
first cycle of the state: a state with a timer of ``n`` cycles lasts exactly ``n`` cycles.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import check_cycles

from ..helpers import rejecting
from .chars import ErrorCounts, LinkState

__all__ = ["LinkFSM"]


class LinkFSM(wiring.Component):
    """The exchange-level link state machine.

    Parameters
    ----------
    reset_cycles : int
        Time spent in Error-Reset, cycles (320 = 6.4 µs at 50 MHz).
    wait_cycles : int
        Time spent in Error-Wait, and the Started/Connecting timeout, cycles (640 = 12.8 µs).

    Attributes
    ----------
    got_null, got_fct, got_nchar, got_time : In(1)
        Receiver conditions (``got_null`` is a level, the others strobes).
    err_disconnect, err_parity, err_escape, err_credit, err_starved : In(1)
        Link errors (``err_starved``: the credit timeout of a lost FCT, counted as
        ``credit_timeout``).
    link_start, auto_start, link_disable, fct_room : In(1)
        Start conditions (see module docstring).
    state : Out(LinkState)
    go_reset : Out(1)
        The machine leaves its state for Error-Reset at the end of this cycle.
    errors : Out(ErrorCounts)
        Saturating counts of the errors that took the link to Error-Reset, per class.
    """

    got_null:       In(1)
    got_fct:        In(1)
    got_nchar:      In(1)
    got_time:       In(1)
    err_disconnect: In(1)
    err_parity:     In(1)
    err_escape:     In(1)
    err_credit:     In(1)
    err_starved:    In(1)
    link_start:     In(1)
    auto_start:     In(1)
    link_disable:   In(1)
    fct_room:       In(1)
    state:          Out(LinkState)
    go_reset:       Out(1)
    errors:         Out(ErrorCounts)

    def __init__(self, *, reset_cycles: int, wait_cycles: int):
        with rejecting(self):
            check_cycles(reset_cycles, "Reset time")
            check_cycles(wait_cycles, "Wait time")
        self._reset_cycles = reset_cycles
        self._wait_cycles = wait_cycles
        super().__init__()

    def elaborate(self, platform):
        m = Module()

        timer = Signal(range(max(self._reset_cycles, self._wait_cycles)))
        m.d.sync += timer.eq(timer + 1)

        rx_error  = self.err_disconnect | self.err_parity | self.err_escape
        seq_error = self.got_fct | self.got_nchar | self.got_time
        enabled   = (~self.link_disable & self.fct_room &
                     (self.link_start | (self.auto_start & self.got_null)))
        wait_over = timer == self._wait_cycles - 1

        def goto(name):
            m.next = name
            m.d.sync += timer.eq(0)

        def reset_on(condition):
            with m.If(condition):
                goto("Error-Reset")
                m.d.comb += self.go_reset.eq(1)

        # Which error classes are counted in this state (those that take it to Error-Reset).
        counted = {
            "disconnect": Signal(), "parity": Signal(), "escape": Signal(),
            "credit": Signal(), "sequence": Signal(), "credit_timeout": Signal(),
        }

        def count_rx_errors():
            m.d.comb += [
                counted["disconnect"].eq(self.err_disconnect),
                counted["parity"].eq(self.err_parity),
                counted["escape"].eq(self.err_escape),
            ]

        with m.FSM(name="link"):
            with m.State("Error-Reset"):
                m.d.comb += self.state.eq(LinkState.ERROR_RESET)
                with m.If(timer == self._reset_cycles - 1):
                    goto("Error-Wait")

            with m.State("Error-Wait"):
                m.d.comb += self.state.eq(LinkState.ERROR_WAIT)
                count_rx_errors()
                m.d.comb += counted["sequence"].eq(seq_error)
                reset_on(rx_error | seq_error)
                with m.Elif(wait_over):
                    goto("Ready")

            with m.State("Ready"):
                m.d.comb += self.state.eq(LinkState.READY)
                count_rx_errors()
                m.d.comb += counted["sequence"].eq(seq_error)
                reset_on(rx_error | seq_error)
                with m.Elif(enabled):
                    goto("Started")

            with m.State("Started"):
                m.d.comb += self.state.eq(LinkState.STARTED)
                count_rx_errors()
                m.d.comb += counted["sequence"].eq(seq_error)
                reset_on(rx_error | seq_error | wait_over)
                with m.Elif(self.got_null):
                    goto("Connecting")

            with m.State("Connecting"):
                m.d.comb += self.state.eq(LinkState.CONNECTING)
                count_rx_errors()
                m.d.comb += counted["sequence"].eq(self.got_nchar | self.got_time)
                reset_on(rx_error | self.got_nchar | self.got_time | wait_over)
                with m.Elif(self.got_fct):
                    goto("Run")

            with m.State("Run"):
                m.d.comb += self.state.eq(LinkState.RUN)
                count_rx_errors()
                m.d.comb += [
                    counted["credit"].eq(self.err_credit),
                    counted["credit_timeout"].eq(self.err_starved),
                ]
                reset_on(rx_error | self.err_credit | self.err_starved | self.link_disable)

        for name, event in counted.items():
            counter = getattr(self.errors, name)
            with m.If(event & (counter != (1 << len(counter)) - 1)):
                m.d.sync += counter.eq(counter + 1)
        return m
