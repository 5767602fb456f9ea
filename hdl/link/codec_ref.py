"""Bit-exact, cycle-level Python reference of :class:`hdl.link.codec.Codec`.

Same parameters, same ports, same registers: each :meth:`CodecRef.step` is one clock cycle of
the gateware, with the line as ``slots``-bit integers (bit 0 = earliest slot). Every output of
the gateware is a function of its registers only (inputs act at the next clock edge), so a
cycle reads :meth:`CodecRef.outputs` first and then calls :meth:`CodecRef.step` with that
cycle's inputs. The tests run it against the RTL cycle for cycle; the co-simulation's fast
``model`` backend runs it instead of the RTL. Plain ints only, no Amaranth at run time.

# Ref: ECSS-E-ST-50-12C §6-§8, as implemented in hdl/link (see docs/link.md).
"""

from __future__ import annotations

from typing import NamedTuple

from mrm_cosim.protocol.link import (CREDIT_AUDIT, CREDIT_TIMEOUT, DEFAULT_RUN_DIV,
                                     DEFAULT_SLOTS, ERROR_CLASSES, FCT_CREDIT, GROUP_BITS,
                                     MAX_CREDIT, NULL_PATTERN, CharKind, LinkState,
                                     codec_params, min_div, rest_credit)
from mrm_cosim.protocol.packet import COUNTER_MAX

__all__ = ["CodecRef", "CodecOutputs", "char_value", "char_fields", "saturating_sum_ref"]

_ER, _EW, _READY, _STARTED, _CONNECTING, _RUN = (s.value for s in LinkState)
_DATA, _EOP, _EEP = CharKind.DATA.value, CharKind.EOP.value, CharKind.EEP.value


def char_value(kind: int, data: int = 0) -> int:
    """Pack an N-char as the gateware's :class:`~hdl.link.chars.Char` (``kind | data << 2``)."""
    return int(kind) | (int(data) & 0xFF) << 2


def char_fields(value: int) -> tuple[int, int]:
    """Unpack a :class:`~hdl.link.chars.Char` value into ``(kind, data)``."""
    return value & 3, (value >> 2) & 0xFF


def saturating_sum_ref(values, width: int = 16) -> int:
    """Reference of :func:`~mrm_cosim.hdl.link.chars.saturating_sum`: the sum of ``values``
    saturated at ``2**width - 1`` (how a node reports its codecs' error classes as one)."""
    return min(sum(int(v) for v in values), (1 << width) - 1)


class CodecOutputs(NamedTuple):
    """Outputs of one cycle (names as the gateware's ports)."""

    tx_ready:   int
    rx_valid:   int
    rx_payload: int     # Char value, meaningful when rx_valid
    tick_out:   int
    time_out:   int
    running:    int
    state:      int     # LinkState value
    errors:     dict    # class name -> count
    tx_credit:  int
    rx_credit:  int
    d_out:      int
    s_out:      int


def _range_mask(n: int) -> int:
    """Wrap-around mask of an Amaranth ``Signal(range(n))``."""
    return (1 << max(1, (n - 1).bit_length())) - 1


class CodecRef:
    """Cycle-level model of one codec; parameters as :class:`hdl.link.codec.Codec`."""

    def __init__(self, *, slots: int = DEFAULT_SLOTS, start_div: int | None = None,
                 run_div: int = DEFAULT_RUN_DIV, max_run_div: int | None = None,
                 reset_cycles: int = 320, wait_cycles: int = 640, disconnect_cycles: int = 43,
                 rx_fifo_depth: int = 64, credit_timeout: int = CREDIT_TIMEOUT,
                 credit_audit: int = CREDIT_AUDIT):
        params = codec_params(slots=slots, start_div=start_div, run_div=run_div,
                              max_run_div=max_run_div, reset_cycles=reset_cycles,
                              wait_cycles=wait_cycles,
                              disconnect_cycles=disconnect_cycles, rx_fifo_depth=rx_fifo_depth,
                              credit_timeout=credit_timeout, credit_audit=credit_audit)
        for name, value in params.items():
            setattr(self, name, value)
        self._limit = self.disconnect_cycles - 2
        self._timer_mask = _range_mask(max(self.reset_cycles, self.wait_cycles))
        self._buf_mask = (1 << (GROUP_BITS + self.slots - 1)) - 1
        self._div_mask = _range_mask(self.max_run_div + 1)
        self._min_div = min_div(self.slots)
        self._refill = -(-self.slots // self._min_div)     # most bits a cycle can take
        self._rest = rest_credit(self.rx_fifo_depth)
        self.reset()

    def reset(self):
        """Power-on state: every register zero, the link in Error-Reset."""
        # Line front end.
        self.d_q = self.s_q = self.d_l = self.s_l = 0
        # Character receiver.
        self.got_null = self.search = self.pos = self.ctrl = self.par = self.shift = 0
        self.pend_valid = self.pend_ctrl = self.pend_bits = self.esc = 0
        self.got_fct = self.got_nchar = self.got_time = 0
        self.nchar = 0
        self.time = 0
        self.err_parity = self.err_escape = 0
        self.armed = self.quiet = 0
        # Link state machine.
        self.state = _ER
        self.timer = 0
        self.errors = dict.fromkeys(ERROR_CLASSES, 0)
        # Transmitter.
        self.buf = self.cnt = self.left = self.d_out = self.s_out = 0
        self.tx_par = 0
        self.run_div_q = self.run_div       # the run-rate register (port `run_div` registered)
        # Credits, FIFO, packet bookkeeping, time-codes.
        self.tx_credit = self.rx_credit = 0
        self.eep_pending = self.rx_in_packet = 0
        self.starved = 0
        self.silent = 0                     # cycles without an N-char sent (credit audit)
        self.discard = self.tx_in_packet = 0
        self.tc_pending = self.tc_value = 0
        self.fifo = [0] * self.rx_fifo_depth
        self.produce = self.consume = self.level = 0

    # -- combinational helpers (functions of the registers only) -----------------------------

    def _fct_room(self) -> bool:
        return (self.rx_credit <= MAX_CREDIT - FCT_CREDIT and
                self.level + self.rx_credit + FCT_CREDIT + 1 <= self.rx_fifo_depth)

    def _ds_slots(self):
        """This cycle's line slots: (d, s, left after, bits taken, remaining, ready)."""
        slots = self.slots
        enable = self.state in (_STARTED, _CONNECTING, _RUN)
        run_div = min(max(self.run_div_q, self._min_div), self.max_run_div)
        div_m1 = (run_div if self.state == _RUN else self.start_div) - 1
        d = (self.d_out >> (slots - 1)) & 1
        s = (self.s_out >> (slots - 1)) & 1
        lft, taken, cnt, buf = self.left, 0, self.cnt, self.buf
        dv = sv = 0
        for i in range(slots):
            if lft == 0 and taken < cnt:
                bit = (buf >> taken) & 1
                if bit == d:
                    s ^= 1
                d = bit
                taken += 1
                lft = div_m1
            elif lft != 0:
                lft -= 1
            dv |= d << i
            sv |= s << i
        remain = cnt - taken
        return dv, sv, lft, taken, remain, enable and remain < self._refill

    def _tx_ready(self, ds_ready: bool) -> bool:
        running = self.state == _RUN
        send_fct = self.state in (_CONNECTING, _RUN) and self._fct_room()
        nchar_ok = running and self.tx_credit != 0 and not self.discard
        return bool(self.discard or (nchar_ok and ds_ready and not self.tc_pending
                                     and not send_fct))

    def outputs(self) -> CodecOutputs:
        """The outputs of the current cycle."""
        ready = self._ds_slots()[5]
        running = self.state == _RUN
        return CodecOutputs(
            tx_ready=int(self._tx_ready(ready)),
            rx_valid=int(self.level != 0),
            rx_payload=self.fifo[self.consume],
            tick_out=int(self.got_time and running),
            time_out=self.time,
            running=int(running),
            state=self.state,
            errors=dict(self.errors),
            tx_credit=self.tx_credit,
            rx_credit=self.rx_credit,
            d_out=self.d_out,
            s_out=self.s_out,
        )

    # -- one clock cycle ----------------------------------------------------------------------

    def step(self, d_in: int = 0, s_in: int = 0, tx_valid: int = 0, tx_payload: int = 0,
             rx_ready: int = 0, tick_in: int = 0, time_in: int = 0, link_start: int = 0,
             auto_start: int = 0, link_disable: int = 0, run_div: int | None = None):
        """Advance one cycle with these inputs (``tx_payload`` is a Char value; ``run_div``
        None: the port left undriven, i.e. its reset value ``self.run_div``)."""
        slots = self.slots
        state = self.state
        running = state == _RUN
        connecting = state == _CONNECTING

        # Receiver outputs and the line front end (registered samples of the last cycle).
        got_fct, got_nchar, got_time = self.got_fct, self.got_nchar, self.got_time
        nchar = self.nchar
        err_disc = self.armed and self.quiet == self._limit
        x_prev = self.d_l ^ self.s_l
        dq, sq = self.d_q, self.s_q
        xq = dq ^ sq
        bit_valid = xq ^ (((xq << 1) | x_prev) & ((1 << slots) - 1))
        line_prev_d = ((dq << 1) | self.d_l) & ((1 << slots) - 1)
        line_prev_s = ((sq << 1) | self.s_l) & ((1 << slots) - 1)
        activity = (dq ^ line_prev_d) | (sq ^ line_prev_s) != 0

        # Credits and flow control.
        fct_room = self._fct_room()
        fct_overflow = got_fct and self.tx_credit > MAX_CREDIT - FCT_CREDIT
        rx_take = got_nchar and running and self.rx_credit != 0
        err_credit = running and (fct_overflow or (got_nchar and self.rx_credit == 0))
        starving = (self.credit_timeout and running and self.rx_in_packet and
                    self.rx_credit != 0 and not got_nchar)
        err_starved = bool(starving and self.starved == self.credit_timeout - 1)
        low, high = self._rest
        err_starved = err_starved or bool(
            self.credit_audit and running and self.silent == self.credit_audit - 1 and
            not low < self.tx_credit <= high)

        # Link state machine.
        rx_error = err_disc or self.err_parity or self.err_escape
        seq_error = got_fct or got_nchar or got_time
        wait_over = self.timer == self.wait_cycles - 1
        next_state, timer = state, (self.timer + 1) & self._timer_mask
        counted = dict.fromkeys(ERROR_CLASSES, False)
        go_reset = False
        if state == _ER:
            if self.timer == self.reset_cycles - 1:
                next_state = _EW
        elif state == _RUN:
            counted.update(disconnect=err_disc, parity=self.err_parity,
                           escape=self.err_escape, credit=err_credit,
                           credit_timeout=err_starved)
            go_reset = rx_error or err_credit or err_starved or link_disable
        else:
            counted.update(disconnect=err_disc, parity=self.err_parity, escape=self.err_escape)
            if state == _CONNECTING:
                counted["sequence"] = got_nchar or got_time
                go_reset = rx_error or got_nchar or got_time or wait_over
                if not go_reset and got_fct:
                    next_state = _RUN
            else:
                counted["sequence"] = seq_error
                go_reset = rx_error or seq_error or (state == _STARTED and wait_over)
                if go_reset:
                    pass
                elif state == _EW:
                    if wait_over:
                        next_state = _READY
                elif state == _READY:
                    if (not link_disable and fct_room and
                            (link_start or (auto_start and self.got_null))):
                        next_state = _STARTED
                elif self.got_null:     # Started
                    next_state = _CONNECTING
        if go_reset:
            next_state = _ER
        if next_state != state:
            timer = 0
        leave_run = running and go_reset
        for name, event in counted.items():
            if event and self.errors[name] != COUNTER_MAX:
                self.errors[name] += 1

        # Transmitter: what to encode if the line can take a group this cycle.
        dv, sv, lft, taken, remain, ds_ready = self._ds_slots()
        tx_enable = state in (_STARTED, _CONNECTING, _RUN)
        send_time = self.tc_pending
        send_fct = (connecting or running) and fct_room
        nchar_ok = running and self.tx_credit != 0 and not self.discard
        tx_ready = self._tx_ready(ds_ready)
        tx_take = tx_valid and tx_ready
        tx_sent = tx_take and not self.discard
        tx_kind, tx_data = char_fields(tx_payload)
        par = self.tx_par
        time_sent = fct_sent = False
        if send_time:
            group = par | 0x0E | 1 << 4 | self.tc_value << 6     # ESC, then P=1 0 T0..T7
            length, par_new = 14, bin(self.tc_value).count("1") & 1
            time_sent = ds_ready
        elif send_fct:
            group, length, par_new = par | 0b0010, 4, 0
            fct_sent = ds_ready
        elif tx_valid and nchar_ok:
            if tx_kind == _DATA:
                group, length = (par ^ 1) | tx_data << 2, 10
                par_new = bin(tx_data).count("1") & 1
            else:
                group = par | (0b1010 if tx_kind == _EOP else 0b0110)
                length, par_new = 4, 1
        else:
            group, length, par_new = par | 0x2E, 8, 0     # NULL: ESC, then FCT with P=0

        # FIFO.
        w_en = self.eep_pending or rx_take
        w_rdy = self.level != self.rx_fifo_depth
        do_write = w_en and w_rdy
        do_read = rx_ready and self.level != 0

        # ---- clock edge ----
        # Receiver.
        if state == _ER:
            self._reset_receiver()
        else:
            self._receive(bit_valid, dq)
            if activity:
                self.quiet = 0
            elif self.armed and self.quiet != self._limit:
                self.quiet += 1
            self.armed = self.armed or activity
        self.d_l, self.s_l = (dq >> (slots - 1)) & 1, (sq >> (slots - 1)) & 1
        self.d_q, self.s_q = d_in, s_in

        # Transmitter.
        self.run_div_q = (self.run_div if run_div is None else run_div) & self._div_mask
        if not tx_enable:
            # Controlled reset: S falls first, D (if high with S) one cycle later.
            d_last = (self.d_out >> (slots - 1)) & (self.s_out >> (slots - 1)) & 1
            self.d_out = (1 << slots) - 1 if d_last else 0
            self.buf = self.cnt = self.left = self.s_out = 0
            self.tx_par = 0
        else:
            self.d_out, self.s_out, self.left = dv, sv, lft
            buf = self.buf >> taken
            if ds_ready:
                self.buf = (buf | group << remain) & self._buf_mask
                self.cnt = remain + length
                self.tx_par = par_new
            else:
                self.buf, self.cnt = buf, remain

        # FIFO and receive-side packet bookkeeping.
        if do_write:
            self.fifo[self.produce] = char_value(_EEP) if self.eep_pending else nchar
            self.produce = (self.produce + 1) % self.rx_fifo_depth
        if do_read:
            self.consume = (self.consume + 1) % self.rx_fifo_depth
        self.level += int(bool(do_write)) - int(bool(do_read))
        self.starved = self.starved + 1 if starving and not err_starved else 0
        rx_in_after = (nchar & 3) == _DATA if rx_take else self.rx_in_packet
        if self.eep_pending:
            if w_rdy:
                self.eep_pending = self.rx_in_packet = 0
        else:
            self.eep_pending = int(bool(leave_run and rx_in_after))
            self.rx_in_packet = int(bool(rx_in_after))

        # Credit audit: cycles without an N-char sent, saturating at the audit time.
        if self.credit_audit:
            if not running or tx_sent:
                self.silent = 0
            elif self.silent != self.credit_audit - 1:
                self.silent += 1

        # Transmit-side packet bookkeeping.
        tx_in_after = (tx_kind == _DATA) if tx_take else self.tx_in_packet
        self.tx_in_packet = int(bool(tx_in_after))
        if self.discard:
            if tx_take and tx_kind != _DATA:
                self.discard = 0
        elif leave_run and tx_in_after:
            self.discard = 1

        # Time-codes.
        if not running:
            self.tc_pending = 0
        elif tick_in:
            self.tc_pending, self.tc_value = 1, time_in & 0xFF
        elif time_sent:
            self.tc_pending = 0

        # Credits.
        if connecting or running:
            self.tx_credit += (FCT_CREDIT if got_fct and not fct_overflow else 0) - int(
                bool(tx_sent))
            self.rx_credit += (FCT_CREDIT if fct_sent else 0) - int(bool(rx_take))
        else:
            self.tx_credit = self.rx_credit = 0

        self.state, self.timer = next_state, timer

    # -- receiver internals -------------------------------------------------------------------

    def _reset_receiver(self):
        self.got_null = self.search = self.pos = self.ctrl = self.par = self.shift = 0
        self.pend_valid = self.pend_ctrl = self.pend_bits = self.esc = 0
        self.got_fct = self.got_nchar = self.got_time = 0
        self.nchar = self.time = 0
        self.err_parity = self.err_escape = 0
        self.armed = self.quiet = 0

    def _receive(self, bit_valid: int, bit_data: int):
        """Frame this cycle's bits; update the receiver's registers and event strobes."""
        got_fct = got_nchar = got_time = perr = eerr = 0
        got_null, search, pos, ctrl = self.got_null, self.search, self.pos, self.ctrl
        par, shift, esc = self.par, self.shift, self.esc
        pend_valid, pend_ctrl, pend_bits = self.pend_valid, self.pend_ctrl, self.pend_bits
        for i in range(self.slots):
            if not (bit_valid >> i) & 1:
                continue
            b = (bit_data >> i) & 1
            if not got_null:
                search = ((search << 1) | b) & 0x7F
                if search == NULL_PATTERN:
                    got_null, pos, par, pend_valid, esc = 1, 0, 0, 0, 0
            elif pos == 0:
                par ^= b
                pos = 1
            elif pos == 1:
                if not (par ^ b):
                    perr = 1
                elif pend_valid:
                    if pend_ctrl:
                        code = pend_bits >> 6
                        if esc:
                            esc = 0
                            if code != 0b00:
                                eerr = 1
                        elif code == 0b00:
                            got_fct = 1
                        elif code == 0b10:
                            got_nchar, self.nchar = 1, char_value(_EOP)
                        elif code == 0b01:
                            got_nchar, self.nchar = 1, char_value(_EEP)
                        else:
                            esc = 1
                    elif esc:
                        got_time, self.time, esc = 1, pend_bits, 0
                    else:
                        got_nchar, self.nchar = 1, char_value(_DATA, pend_bits)
                ctrl, par, pos, pend_valid = b, 0, 2, 0
            else:
                shift = (shift >> 1) | (b << 7)
                par ^= b
                if pos == (3 if ctrl else 9):
                    pend_valid, pend_ctrl, pend_bits, pos = 1, ctrl, shift, 0
                else:
                    pos += 1
        self.got_null, self.search, self.pos, self.ctrl = got_null, search, pos, ctrl
        self.par, self.shift, self.esc = par, shift, esc
        self.pend_valid, self.pend_ctrl, self.pend_bits = pend_valid, pend_ctrl, pend_bits
        self.got_fct, self.got_nchar, self.got_time = got_fct, got_nchar, got_time
        self.err_parity |= perr
        self.err_escape |= eerr
