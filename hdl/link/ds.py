"""Data-strobe SERDES: ``slots`` line samples per 20 ns node-clock cycle on D and S.

# Ref: ECSS-E-ST-50-12C §6.3 (data-strobe encoding), §6.6 (data signalling rate).

Data-strobe encoding sends each bit on D; S changes whenever D does not, so exactly one of
the two lines changes per bit and ``D xor S`` toggles once per bit. Here the line is modelled
as ``slots`` equal time slots per clock cycle (a SERDES of width ``slots``): ``d_out[0]`` is the
earliest slot of a cycle. With ``slots = 3`` a slot is 6.67 ns, so one bit per slot is
150 Mbit/s and 15 slots per bit is 10 Mbit/s.

:class:`DSTransmitter` shifts out groups of line bits (one character, NULL or time-code at a
time) at a bit period of ``start_div`` slots before Run and ``run_div`` slots in Run, the latter
a register the host may change at any time (§6.6: the rate may change in Run). When disabled it
takes the line to zero without a simultaneous transition of D and S: S falls first, D one cycle
later. :class:`DSReceiver` marks the slots of each cycle in which ``D xor S`` changed (each
carries a new bit whose value is D) and registers the result. It decodes a peer whose
transitions are at least one sample period apart (docs/link.md "Receiver margin").
"""

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import GROUP_BITS, check_div, check_slots, min_div

from ..helpers import rejecting

__all__ = ["TxBits", "DSTransmitter", "DSReceiver"]


class TxBits(data.Struct):
    """A group of line bits to transmit, ``bits[0]`` first."""

    bits:   GROUP_BITS
    length: range(GROUP_BITS + 1)


class DSTransmitter(wiring.Component):
    """Data-strobe transmitter producing ``slots`` line samples per cycle.

    Parameters
    ----------
    slots : int
        Line slots per clock cycle (1 to 4).
    start_div : int
        Bit period in slots while ``fast`` is low (link start-up, 10 Mbit/s).
    max_run_div : int
        Longest bit period ``run_div`` may select.

    Attributes
    ----------
    enable : In(1)
        Low: the transmitter is reset and the lines go low without a simultaneous transition
        (ECSS-E-ST-50-12C Rev.1's controlled reset of an output port): S falls in the first
        disabled cycle, D (if it was high with S) in the next, one cycle = ``slots`` slots later.
    fast : In(1)
        Selects ``run_div`` for every bit that starts while it is high.
    run_div : In(range(max_run_div + 1))
        Bit period in slots while ``fast`` is high, clamped to ``min_div(slots)`` …
        ``max_run_div``; takes effect from the next bit that starts.
    groups : In(stream.Signature(TxBits))
        Bit groups to send. ``ready`` is high, whatever ``valid`` is, in the cycles where fewer
        bits would remain queued after this cycle's slots than a cycle can take at most
        (``ceil(slots / min_div(slots))``: ``slots`` up to 4, 3 at 6): a group accepted then
        follows the queued bits without a gap.
    d_out, s_out : Out(slots)
        Registered line samples, bit 0 = earliest slot.
    """

    def __init__(self, *, slots: int, start_div: int, max_run_div: int):
        with rejecting(self):
            check_slots(slots)
            check_div(start_div, "Start bit period", slots)
            check_div(max_run_div, "Slowest run bit period", slots)
        self._slots = slots
        self._start_div = start_div
        self._max_run_div = max_run_div
        super().__init__({
            "enable":  In(1),
            "fast":    In(1),
            "run_div": In(range(max_run_div + 1)),
            "groups": In(stream.Signature(TxBits)),
            "d_out":  Out(slots),
            "s_out":  Out(slots),
        })

    def elaborate(self, platform):
        m = Module()
        slots = self._slots

        buf  = Signal(GROUP_BITS + slots - 1)          # queued line bits, bit 0 next
        cnt  = Signal(range(len(buf) + 1))             # how many of them are valid
        left = Signal(range(max(self._start_div, self._max_run_div)))  # slots left in this bit

        lo, hi = min_div(slots), self._max_run_div
        run_div = Signal(range(hi + 1))                 # run_div clamped to lo … hi
        m.d.comb += run_div.eq(Mux(self.run_div < lo, lo,
                                   Mux(self.run_div > hi, hi, self.run_div)))

        # The bits this cycle takes, in closed form: the walk above starts a bit in slot
        # `left` (if `left < slots`) and then every `div` slots, as long as bits remain, so it
        # takes min(cnt, starts(left, div)) of them — the same number as its chain of per-slot
        # sums, without that chain on the path to `ready` (and from there to the codec's
        # credit counters), which limited the codec's clock (50.6 MHz on an ECP5).
        # With a run-time bit period the table has a row per period up to `slots` (any longer
        # period starts at most one bit per cycle, like `slots`).
        def starts(lft0, div):
            return 0 if lft0 >= slots else 1 + (slots - 1 - lft0) // div

        n_start = Signal(range(slots + 1))
        n_run = Signal(range(slots + 1))
        short = Signal(range(slots + 1))                 # run_div, or `slots` if longer
        m.d.comb += short.eq(Mux(run_div > slots, slots, run_div))
        with m.Switch(left):
            for lft0 in range(slots):
                with m.Case(lft0):
                    m.d.comb += [
                        n_start.eq(starts(lft0, self._start_div)),
                        n_run.eq(Array(Const(starts(lft0, max(div, lo)), range(slots + 1))
                                       for div in range(slots + 1))[short]),
                    ]
        n_starts = Signal(range(slots + 1))
        m.d.comb += n_starts.eq(Mux(self.fast, n_run, n_start))
        # The bits taken, min(n_starts, cnt), one-hot: n_starts is at most `max_take`
        # (ceil(slots / min_div)), and the queue after the cycle is picked among that many
        # shifts of it, each formed from the registers, rather than shifted by a count that
        # is itself a minimum after the tables (the node's slowest path after the receiver's
        # decode and `ready` were cut).
        max_take = -(-slots // lo)
        more = [n_starts > t for t in range(max_take + 1)]
        takes = [((n_starts == t) & (cnt >= t if t else 1)) | ((cnt == t) & more[t])
                 for t in range(max_take + 1)]

        # Each slot's line levels in closed form too. The walk of the slots (the reference,
        # hdl/link/codec_ref.py) starts a bit in a slot where the previous bit is over: in slot
        # `left` (if `left < slots`) and then every `div` slots while bits remain. So by slot i
        # it has started n_i = min(cnt, t_i) bits, t_i = 0 before slot `left`, else
        # 1 + (i − left) // div (a table over `left` and the period, as above); D is the last
        # of them (or stays), and D xor S has toggled once per bit. Unrolled as a chain over
        # six slots, the walk was the slowest path of the node (25 ns on an ECP5).
        d_last, s_last = self.d_out[-1], self.s_out[-1]
        ds_last = d_last ^ s_last
        d_slots, s_slots = [], []
        for i in range(slots):
            t_start = Signal(range(slots + 1), name=f"t_start_{i}")
            t_run = Signal(range(slots + 1), name=f"t_run_{i}")

            def upto(lft0, div, i=i):
                return 0 if lft0 > i else 1 + (i - lft0) // div

            with m.Switch(left):
                for lft0 in range(i + 1):
                    with m.Case(lft0):
                        m.d.comb += [
                            t_start.eq(upto(lft0, self._start_div)),
                            t_run.eq(Array(Const(upto(lft0, max(div, lo)), range(slots + 1))
                                           for div in range(slots + 1))[short]),
                        ]
            t_i = Mux(self.fast, t_run, t_start)
            n_i = Signal(range(slots + 1), name=f"started_{i}")
            m.d.comb += n_i.eq(Mux(t_i < cnt, t_i, cnt))
            d_i = Signal(name=f"d_{i}")
            m.d.comb += d_i.eq(Mux(n_i == 0, d_last,
                                   Array(buf[k] for k in range(i + 1))[n_i - 1]))
            d_slots.append(d_i)
            s_slots.append(d_i ^ ds_last ^ n_i[0])
        # `left` after this cycle: with no bit to start it only counts down (left − slots, or
        # 0); if the bits ran out before every start (cnt < n_starts) the last one is over
        # within the cycle (0); else the last start, in slot left + (n_starts − 1)·div, runs on
        # for div slots: left + n_starts·div − slots, a table again (one start per cycle when
        # div > slots: left + div − slots). No product on the path.
        def after(lft0, div):
            return max(lft0 + starts(lft0, div) * div - slots, 0)

        lft_full = Signal.like(left)
        with m.Switch(left):
            for lft0 in range(slots):
                with m.Case(lft0):
                    run_full = Mux(run_div > slots, lft0 + run_div - slots,
                                   Array(Const(after(lft0, max(div, lo)), len(left))
                                         for div in range(slots + 1))[short])
                    m.d.comb += lft_full.eq(Mux(self.fast, run_full,
                                                after(lft0, self._start_div)))
            with m.Default():
                m.d.comb += lft_full.eq(left - slots)
        lft = Mux(cnt < n_starts, 0, lft_full)
        remain = Signal.like(cnt)
        # Refill when fewer bits remain than a cycle can take at most (`slots` up to 4 slots,
        # 3 at 6 slots): the line never starves (a group is at least 4 bits), and a character
        # is chosen as late as that allows, the same cycle as with one slot per bit.
        # remain < refill, i.e. cnt − min(n_starts, cnt) < refill, is cnt < n_starts + refill:
        # with cnt − refill formed from the register, one compare after the tables rather than
        # a minimum, a difference and a compare (that chain, through the codec's `ready` into
        # its credit counter, was the node's slowest path once the receiver's decode was cut).
        refill = -(-slots // lo)
        cnt_less = Signal.like(cnt)
        m.d.comb += [
            remain.eq(_pick(takes, [(cnt - t)[:len(cnt)] for t in range(max_take + 1)])),
            cnt_less.eq(cnt - refill),
            self.groups.ready.eq(self.enable & ((cnt < refill) | (cnt_less < n_starts))),
        ]

        with m.If(~self.enable):
            # Controlled reset: S falls first; D keeps its level for one more cycle if S was
            # high with it, so D and S never change in the same slot.
            m.d.sync += [
                buf.eq(0),
                cnt.eq(0),
                left.eq(0),
                self.d_out.eq(Mux(self.d_out[-1] & self.s_out[-1], (1 << slots) - 1, 0)),
                self.s_out.eq(0),
            ]
        with m.Else():
            m.d.sync += [
                self.d_out.eq(Cat(d_slots)),
                self.s_out.eq(Cat(s_slots)),
                left.eq(lft),
            ]
            with m.If(self.groups.valid & self.groups.ready):
                m.d.sync += [
                    buf.eq(_pick(takes, [(buf >> t) | (self.groups.p.bits << (cnt - t)[:len(cnt)])
                                         for t in range(max_take + 1)])),
                    cnt.eq(_pick(takes, [(cnt + self.groups.p.length - t)[:len(cnt)]
                                         for t in range(max_take + 1)])),
                ]
            with m.Else():
                m.d.sync += [
                    buf.eq(_pick(takes, [buf >> t for t in range(max_take + 1)])),
                    cnt.eq(remain),
                ]
        return m


class DSReceiver(wiring.Component):
    """Data-strobe receiver front end: finds the bits on the line, one cycle later.

    Parameters
    ----------
    slots : int
        Line slots per clock cycle (1 to 4).

    Attributes
    ----------
    d_in, s_in : In(slots)
        Line samples, bit 0 = earliest slot.
    bit_valid : Out(slots)
        Registered: slot ``i`` of the previous cycle's samples started a new bit
        (``D xor S`` changed from the slot before it).
    bit_data : Out(slots)
        Registered: the bit value (D) in each of those slots.
    packed_valid, packed_data : Out(slots)
        Registered: the same bits packed, the first in bit 0: ``packed_valid`` is a thermometer
        code of their count (bit ``k`` high: more than ``k`` bits), ``packed_data`` their values
        (zero above the count). The character receiver decodes these; packing them here,
        before the register this stage has anyway, takes the sparse slots off its paths.
    activity : Out(1)
        Registered: D or S changed in some slot of the previous cycle (disconnect detection).
    """

    def __init__(self, *, slots: int):
        with rejecting(self):
            check_slots(slots)
        self._slots = slots
        super().__init__({
            "d_in":      In(slots),
            "s_in":      In(slots),
            "bit_valid": Out(slots),
            "bit_data":  Out(slots),
            "packed_valid": Out(slots),
            "packed_data":  Out(slots),
            "activity":  Out(1),
        })

    def elaborate(self, platform):
        m = Module()

        # The decoded slots are registered (rather than the raw samples), so everything
        # downstream sees registers only; the timing is the same as registering the line.
        d_l = Signal()      # last slot of the previous cycle's samples
        s_l = Signal()
        prev_d, prev_s = d_l, s_l
        valid, changes = [], []
        for i in range(self._slots):
            d, s = self.d_in[i], self.s_in[i]
            valid.append((d ^ s) ^ (prev_d ^ prev_s))
            changes.append((d ^ prev_d) | (s ^ prev_s))
            prev_d, prev_s = d, s
        # Packing: the bit of slot i goes to place `before[i]`, the number of bits before it.
        before, count = [], Const(0, range(self._slots + 1))
        for i in range(self._slots):
            before.append(count)
            count = (count + valid[i])[:len(count)]
        packed = [Cat(valid[i] & (before[i] == k) & self.d_in[i]
                      for i in range(k, self._slots)).any() for k in range(self._slots)]
        m.d.sync += [
            self.packed_valid.eq(Cat(count > k for k in range(self._slots))),
            self.packed_data.eq(Cat(packed)),
            d_l.eq(self.d_in[-1]),
            s_l.eq(self.s_in[-1]),
            self.bit_valid.eq(Cat(valid)),
            self.bit_data.eq(self.d_in),
            self.activity.eq(Cat(changes).any()),
        ]
        return m


def _pick(selects, values):
    """The value whose select is high (``selects`` one-hot), as an OR of gated terms."""
    result = Mux(selects[0], values[0], 0)
    for select, value in zip(selects[1:], values[1:], strict=True):
        result = result | Mux(select, value, 0)
    return result
