"""SpaceWire codec: one link endpoint with host character streams, credits and counters.

# Ref: ECSS-E-ST-50-12C §6-§8: data-strobe signalling, characters, link state machine (§8.5),
#      flow control (FCT = 8 N-chars, at most 56 outstanding), link error recovery,
#      time-codes (§8.12).

The codec runs from one 50 MHz clock ("sync"); its line ports carry ``slots`` samples per
cycle (see :mod:`hdl.link.ds`). It starts at 10 Mbit/s (``start_div`` slots per bit) and sends
at the ``run_div`` port's bit period once in Run (150 Mbit/s with the defaults: 6 slots per
cycle, 2 slots per bit, so the receiver takes two samples per bit of a peer at the same rate).

Flow control: ``rx_credit`` counts the N-chars the peer may still send us; an FCT is sent when
it is at most 48 and the receive FIFO has room for 8 more beyond it, keeping one FIFO entry in
reserve for the EEP below. ``tx_credit`` counts what the peer allowed us; each FCT adds 8, and
an FCT that would take it past 56 is a credit error, as is an N-char that arrives when
``rx_credit`` is 0 (the standard's two credit-error rules).

Lost FCTs: an FCT lost on the line breaks neither rule (the peer just holds 8 credits fewer
than we think). It shows when the peer runs dry inside a packet while we still count credit
for it: a packet is open (the last N-char stored was a data character), ``rx_credit`` is not
0, and no N-char arrives for ``credit_timeout`` cycles. That is a ``credit_timeout`` error and
takes the link through Error-Reset, which recovers the credit as the standard recovers it after
any link error: both counts restart from 0 and the handshake's FCTs set them again
(docs/link.md "Lost FCTs").

Credit audit: a lost FCT that never starves the peer (with a 64-entry FIFO it keeps 40-48
credits) is found by the sender of the other direction. Once it has sent no N-char for
``credit_audit`` cycles, the peer has drained its FIFO and granted all it grants at rest
(:func:`~mrm_cosim.protocol.link.rest_credit`, for a peer of our FIFO depth), so ``tx_credit``
must be in that window: below it an FCT of the peer's was lost, above it one appeared. Either is
a ``credit_timeout`` error, recovered by the same restart.

Link errors: every error sends the link through Error-Reset. A packet cut by the error is
ended with an EEP in the receive FIFO, so it never looks good to the host; on the sending side
the rest of the cut packet is taken from the host and dropped, up to and including its
EOP/EEP, so a fragment never starts a later packet.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import (CREDIT_AUDIT, CREDIT_TIMEOUT, DEFAULT_RUN_DIV,
                                     DEFAULT_SLOTS, FCT_CREDIT, MAX_CREDIT, codec_params,
                                     rest_credit)
from mrm_cosim.units import CLOCK_HZ

from ..helpers import rejecting
from .chars import Char, CharKind, ErrorCounts, LinkState
from .ds import DSReceiver
from .fifo import BlockRamFIFO
from .fsm import LinkFSM
from .rx import CharReceiver

from .tx import CharTransmitter

__all__ = ["Codec", "CLOCK_HZ"]


class Codec(wiring.Component):
    """One SpaceWire link endpoint.

    Parameters
    ----------
    slots : int
        Line slots per 20 ns cycle (1 to 8): the SERDES width (6: 300 MS/s).
    start_div : int or None
        Bit period before Run, in slots; ``None`` for 10 Mbit/s (``5 * slots``).
    run_div : int
        Reset value of the ``run_div`` port: the bit period in Run, in slots (2 with 6 slots:
        150 Mbit/s). At least ``ceil(slots / 4)`` (at most 4 bits per cycle).
    max_run_div : int or None
        Longest bit period the ``run_div`` port selects; ``None``: ``start_div`` (10 Mbit/s).
    reset_cycles : int
        Error-Reset time, cycles (320 = 6.4 µs).
    wait_cycles : int
        Error-Wait time and Started/Connecting timeout, cycles (640 = 12.8 µs).
    disconnect_cycles : int
        Cycles from the last line transition to the disconnect error (43: 847-860 ns with
        3 slots; see docs/link.md).
    rx_fifo_depth : int
        Receive FIFO entries (at least 9: 8 for one FCT's worth plus one reserved for an EEP).
    credit_timeout : int
        Cycles an open packet may pause while we count credit for the peer before that is a
        ``credit_timeout`` error (640 = 12.8 µs; 0: never).
    credit_audit : int
        Cycles without an N-char sent after which ``tx_credit`` must be what a drained peer of
        the same FIFO depth grants, else a ``credit_timeout`` error (1280 = 25.6 µs; 0: never).

    Attributes
    ----------
    tx : In(stream.Signature(Char))
        N-chars to send; ``ready`` only in Run with credit left (or while the rest of a cut
        packet is being discarded).
    rx : Out(stream.Signature(Char))
        N-chars received.
    tick_in, time_in : In(1), In(8)
        Send a time-code (strobe; ignored unless running). ``time_in[7:6]`` are the control
        flags, ``time_in[5:0]`` the time.
    tick_out, time_out : Out(1), Out(8)
        A time-code arrived (strobe, Run only); ``time_out`` holds its value until a link reset.
    link_start, auto_start, link_disable : In(1)
        Link control levels (§8.5.3).
    running : Out(1)
        The link is in Run.
    state : Out(LinkState)
        The link state machine's state (§8.5.2), a :class:`LinkState` value.
    errors : Out(ErrorCounts)
        Saturating 16-bit counters of the error classes (disconnect, parity, escape, credit,
        character sequence, credit timeout; :class:`ErrorCounts`, lowest bits first).
    tx_credit, rx_credit : Out(range(57))
        N-chars we may still send / the peer may still send us.
    run_div : In(range(max_run_div + 1))
        Bit period in Run, in slots, a level the host may change at any time (§6.6: the
        transmit rate may change in Run): registered, then used by every bit that starts while
        the link is in Run; values outside ``ceil(slots / 4)`` … ``max_run_div`` are clamped.
        Left undriven it is ``run_div``.
    d_in, s_in, d_out, s_out : In(slots), Out(slots)
        The line, bit 0 = earliest slot of the cycle. Outputs are registered, inputs are
        registered before use.
    """

    def __init__(self, *, slots: int = DEFAULT_SLOTS, start_div: int | None = None,
                 run_div: int = DEFAULT_RUN_DIV, max_run_div: int | None = None,
                 reset_cycles: int = 320, wait_cycles: int = 640, disconnect_cycles: int = 43,
                 rx_fifo_depth: int = 64, credit_timeout: int = CREDIT_TIMEOUT,
                 credit_audit: int = CREDIT_AUDIT):
        with rejecting(self):
            params = codec_params(slots=slots, start_div=start_div, run_div=run_div,
                                  max_run_div=max_run_div, reset_cycles=reset_cycles,
                                  wait_cycles=wait_cycles,
                                  disconnect_cycles=disconnect_cycles,
                                  rx_fifo_depth=rx_fifo_depth, credit_timeout=credit_timeout,
                                  credit_audit=credit_audit)
        self.run_div_init = params.pop("run_div")      # the port below is `run_div`
        for name, value in params.items():
            setattr(self, name, value)
        super().__init__({
            "tx":           In(stream.Signature(Char)),
            "rx":           Out(stream.Signature(Char)),
            "tick_in":      In(1),
            "time_in":      In(8),
            "tick_out":     Out(1),
            "time_out":     Out(8),
            "link_start":   In(1),
            "auto_start":   In(1),
            "link_disable": In(1),
            "running":      Out(1),
            "state":        Out(LinkState),
            "errors":       Out(ErrorCounts),
            "tx_credit":    Out(range(MAX_CREDIT + 1)),
            "rx_credit":    Out(range(MAX_CREDIT + 1)),
            "run_div":      In(range(self.max_run_div + 1), init=self.run_div_init),
            "d_in":         In(self.slots),
            "s_in":         In(self.slots),
            "d_out":        Out(self.slots),
            "s_out":        Out(self.slots),
        })

    def _credit_counters(self, m, rx, tx, fifo, occupied, rx_take, fct_overflow, tx_sent,
                         active):
        """The credits' and ``occupied``'s updates (reset while the link is neither connecting
        nor running, ``active`` low; ``occupied`` then follows the FIFO alone)."""
        tx_credit, rx_credit = self.tx_credit, self.rx_credit
        # The level's change is a write (early: from the receiver) less a read, which comes
        # late: the user's ``ready`` (the router's decision on the FIFO's own output). The
        # credit's change has a late part too, an FCT sent: the transmitter's choice, after
        # its data-strobe stage's ``ready``. Every sum is formed without the late terms, and
        # they only select one (``− 1`` or not, ``+ FCT_CREDIT`` or not), so they meet a mux,
        # not the adders (each was the head of the node's slowest path, docs/node.md "Clock").
        fifo_write = fifo.w_en & fifo.w_rdy
        fifo_read  = fifo.r_en & fifo.r_rdy
        occ_base   = occupied - rx_take + fifo_write
        occ_run    = Mux(tx.fct_sent, occ_base + FCT_CREDIT, occ_base)
        occ_run_rd = Mux(tx.fct_sent, occ_base + (FCT_CREDIT - 1), occ_base - 1)
        occ_idle   = fifo.level + fifo_write
        rx_base    = rx_credit - rx_take
        with m.If(active):
            m.d.sync += [
                tx_credit.eq(tx_credit + Mux(rx.got_fct & ~fct_overflow, FCT_CREDIT, 0)
                             - tx_sent),
                rx_credit.eq(Mux(tx.fct_sent, rx_base + FCT_CREDIT, rx_base)),
                occupied.eq(Mux(fifo_read, occ_run_rd, occ_run)),
            ]
        with m.Else():
            m.d.sync += [tx_credit.eq(0), rx_credit.eq(0),
                         occupied.eq(Mux(fifo_read, occ_idle - 1, occ_idle))]

    def _credit_audit(self, m, err_audit, running, tx_sent):
        """Drive ``err_audit``: silent for the audit time, we must hold a drained peer's
        credit."""
        if not self.credit_audit:
            return
        low, high = rest_credit(self.rx_fifo_depth)
        silent = Signal(range(self.credit_audit))
        m.d.comb += err_audit.eq(running & (silent == self.credit_audit - 1) &
                                 ((self.tx_credit <= low) | (self.tx_credit > high)))
        with m.If(~running | tx_sent):
            m.d.sync += silent.eq(0)
        with m.Elif(silent != self.credit_audit - 1):
            m.d.sync += silent.eq(silent + 1)

    def elaborate(self, platform):
        m = Module()

        m.submodules.ds_rx = ds_rx = DSReceiver(slots=self.slots)
        m.submodules.char_rx = rx = CharReceiver(slots=self.slots,
                                                 disconnect_limit=self.disconnect_cycles - 2)
        m.submodules.char_tx = tx = CharTransmitter(slots=self.slots, start_div=self.start_div,
                                                    max_run_div=self.max_run_div)
        m.submodules.fsm = fsm = LinkFSM(reset_cycles=self.reset_cycles,
                                         wait_cycles=self.wait_cycles)
        m.submodules.fifo = fifo = BlockRamFIFO(width=Char.as_shape().size,
                                                depth=self.rx_fifo_depth)

        state      = fsm.state
        running    = state == LinkState.RUN
        connecting = state == LinkState.CONNECTING
        leave_run  = Signal()
        m.d.comb += [
            self.running.eq(running),
            self.state.eq(state),
            self.errors.eq(fsm.errors),
            leave_run.eq(running & fsm.go_reset),
        ]

        # Line in: front end, then character receiver (held in reset in Error-Reset).
        m.d.comb += [
            ds_rx.d_in.eq(self.d_in),
            ds_rx.s_in.eq(self.s_in),
            rx.enable.eq(state != LinkState.ERROR_RESET),
            rx.bit_valid.eq(ds_rx.packed_valid),
            rx.bit_data.eq(ds_rx.packed_data),
            rx.activity.eq(ds_rx.activity),
        ]

        # Credits and the receive FIFO.
        tx_credit, rx_credit = self.tx_credit, self.rx_credit
        fct_overflow = rx.got_fct & (tx_credit > MAX_CREDIT - FCT_CREDIT)
        rx_take      = rx.got_nchar & running & (rx_credit != 0)
        err_credit   = running & (fct_overflow | (rx.got_nchar & (rx_credit == 0)))
        # ``fifo.level + rx_credit`` kept as a register of its own, updated with both, so that
        # ``fct_room`` is two compares of registers with constants: the sum's adder was the
        # head of the node's slowest path (fifo.level → fct_room → send_fct → the
        # transmitter, docs/node.md "Clock"). It equals the sum in every cycle.
        occupied     = Signal(range(self.rx_fifo_depth + MAX_CREDIT + 1))
        self._occupancy = (occupied, fifo.level, rx_credit)   # (tests/test_codec_flow.py)
        fct_room     = ((rx_credit <= MAX_CREDIT - FCT_CREDIT) &
                        (occupied <= self.rx_fifo_depth - FCT_CREDIT - 1))

        eep_pending  = Signal()     # a packet was cut: put an EEP into the FIFO
        rx_in_packet = Signal()     # the last N-char put into the FIFO was a data character
        eep = Signal(Char)
        m.d.comb += [
            eep.kind.eq(CharKind.EEP),
            fifo.w_en.eq(eep_pending | rx_take),
            fifo.w_data.eq(Mux(eep_pending, eep, rx.nchar)),
            self.rx.valid.eq(fifo.r_rdy),
            self.rx.payload.eq(fifo.r_data),
            fifo.r_en.eq(self.rx.ready),
        ]
        rx_in_after = Mux(rx_take, rx.nchar.kind == CharKind.DATA, rx_in_packet)
        # Lost FCT: an open packet, credit we count for the peer, no N-char for the timeout.
        err_starved = Signal()
        if self.credit_timeout:
            starving = running & rx_in_packet & (rx_credit != 0) & ~rx.got_nchar
            starved  = Signal(range(self.credit_timeout))
            m.d.comb += err_starved.eq(starving & (starved == self.credit_timeout - 1))
            m.d.sync += starved.eq(Mux(starving & ~err_starved, starved + 1, 0))

        err_audit = Signal()        # driven below, with the transmitter

        with m.If(eep_pending):
            with m.If(fifo.w_rdy):
                m.d.sync += [eep_pending.eq(0), rx_in_packet.eq(0)]
        with m.Else():
            m.d.sync += [
                eep_pending.eq(leave_run & rx_in_after),
                rx_in_packet.eq(rx_in_after),
            ]

        # Link state machine.
        m.d.comb += [
            fsm.got_null.eq(rx.got_null),
            fsm.got_fct.eq(rx.got_fct),
            fsm.got_nchar.eq(rx.got_nchar),
            fsm.got_time.eq(rx.got_time),
            fsm.err_disconnect.eq(rx.err_disconnect),
            fsm.err_parity.eq(rx.err_parity),
            fsm.err_escape.eq(rx.err_escape),
            fsm.err_credit.eq(err_credit),
            fsm.err_starved.eq(err_starved | err_audit),
            fsm.link_start.eq(self.link_start),
            fsm.auto_start.eq(self.auto_start),
            fsm.link_disable.eq(self.link_disable),
            fsm.fct_room.eq(fct_room),
        ]

        # Transmitter: NULLs from Started, FCTs from Connecting, everything in Run.
        tc_pending = Signal()
        tc_value   = Signal(8)
        discard    = Signal()       # dropping the rest of a packet cut by a link reset
        tx_in_packet = Signal()     # the last N-char taken from the host was a data character
        nchar_ok = running & (tx_credit != 0) & ~discard
        # The run rate is registered, so that `tx.ready` stays a function of registers.
        run_div = Signal(range(self.max_run_div + 1), init=self.run_div_init)
        m.d.sync += run_div.eq(self.run_div)
        m.d.comb += [
            tx.enable.eq((state == LinkState.STARTED) | connecting | running),
            tx.fast.eq(running),
            tx.run_div.eq(run_div),
            tx.send_time.eq(tc_pending),
            tx.time.eq(tc_value),
            tx.send_fct.eq((connecting | running) & fct_room),
            tx.nchar.valid.eq(self.tx.valid & nchar_ok),
            tx.nchar.payload.eq(self.tx.payload),
            self.tx.ready.eq(discard | (nchar_ok & tx.nchar.ready)),
            self.d_out.eq(tx.d_out),
            self.s_out.eq(tx.s_out),
        ]
        tx_take = self.tx.valid & self.tx.ready
        tx_sent = tx_take & ~discard
        tx_in_after = Mux(tx_take, self.tx.payload.kind == CharKind.DATA, tx_in_packet)
        m.d.sync += tx_in_packet.eq(tx_in_after)
        with m.If(discard):
            with m.If(tx_take & (self.tx.payload.kind != CharKind.DATA)):
                m.d.sync += discard.eq(0)
        with m.Elif(leave_run & tx_in_after):
            m.d.sync += discard.eq(1)

        self._credit_audit(m, err_audit, running, tx_sent)

        with m.If(~running):
            m.d.sync += tc_pending.eq(0)
        with m.Elif(self.tick_in):
            m.d.sync += [tc_pending.eq(1), tc_value.eq(self.time_in)]
        with m.Elif(tx.time_sent):
            m.d.sync += tc_pending.eq(0)

        self._credit_counters(m, rx, tx, fifo, occupied, rx_take, fct_overflow, tx_sent,
                              connecting | running)

        # Time-codes out.
        m.d.comb += [
            self.tick_out.eq(rx.got_time & running),
            self.time_out.eq(rx.time),
        ]
        return m
