"""Two codecs on independent clocks: each line resampled onto the other codec's sample grid.

Each side is a bit-exact :class:`~hdl.link.codec_ref.CodecRef` (the gateware's cycle-level
reference) on its own clock: side ``a`` at the nominal 20 ns, side ``b`` ``ppm`` parts per
million faster (negative: slower), each with its own phase. A codec's line output is a level
per slot (``slots`` equal slots per cycle of *its* clock); the other codec samples it at the
start of each of *its* slots. Times are exact integers (no rounding drift): with
``ppm = n``, a cycle of ``a`` lasts ``(10**6 + n)·L`` time units and one of ``b`` ``10**6·L``,
``L`` the least common multiple of both slot counts. The codecs are stepped in the order of
their cycle ends, so a codec's inputs for a cycle are always taken from line levels the peer
has already produced (every output of a codec is a function of its registers).

Both hosts send a counter byte stream cut into packets (``packet`` data characters and an
EOP), and read everything at once. :func:`run_two_clocks` returns what arrived, the errors
counted and how often each link left Run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import lcm

from mrm_cosim.hdl.link.codec_ref import CodecRef, char_value
from mrm_cosim.protocol.link import slot_at

__all__ = ["ClockRun", "run_two_clocks"]

_RUN = 5


@dataclass
class _Side:
    ref: CodecRef
    cycle_len: int          # time units per cycle
    phase: int              # time of the start of cycle 0
    slots: int
    packet: int
    d_hist: list = field(default_factory=list)     # line output of cycle base + i
    s_hist: list = field(default_factory=list)
    base: int = 0
    cycle: int = 0          # next cycle to step
    sent: int = 0           # characters taken by the codec
    received: int = 0       # characters delivered in order and correct
    wrong: int = 0          # characters delivered that differ from what was sent
    runs: int = 0           # entries into Run
    in_run: bool = False

    def char(self, k: int) -> int:
        """The ``k``-th character this side sends: ``packet`` counter bytes, then an EOP."""
        pkt, pos = divmod(k, self.packet + 1)
        if pos == self.packet:
            return char_value(1)
        return char_value(0, (pkt * self.packet + pos) & 0xFF)

    def level(self, t: int) -> tuple[int, int]:
        """This side's (D, S) at time ``t``; zero before its cycle 0."""
        at = slot_at(t, self.phase, self.cycle_len, self.slots)
        if at is None:
            return 0, 0
        c, k = at
        i = c - self.base
        return (self.d_hist[i] >> k) & 1, (self.s_hist[i] >> k) & 1


@dataclass
class ClockRun:
    """What a two-clock run delivered: per side (``"a"``, ``"b"``) the characters it sent and
    the characters it received intact and in order, wrong characters, error counts and how often
    its link entered Run; ``cycles`` per side."""

    sent: dict
    received: dict
    wrong: dict
    errors: dict
    runs: dict
    cycles: dict

    @property
    def error_free(self) -> bool:
        return (all(r == 1 for r in self.runs.values()) and not any(self.wrong.values())
                and not any(n for e in self.errors.values() for n in e.values()))


def run_two_clocks(ppm: int, *, chars: int, params=None, params_b=None, phase: float = 0.37,
                   packet: int = 40, max_cycles: int | None = None) -> ClockRun:
    """Run until each side has received ``chars`` characters (or ``max_cycles`` cycles of side
    ``a`` passed). ``params`` are the :class:`CodecRef` parameters of both sides
    (``params_b`` overrides side ``b``'s); ``phase`` is ``b``'s clock phase in cycles of ``a``.
    """
    params = dict(params or {})
    pa, pb = params, dict(params, **(params_b or {}))
    ra, rb = CodecRef(**pa), CodecRef(**pb)
    unit = lcm(ra.slots, rb.slots)
    len_a = (10**6 + ppm) * unit
    len_b = 10**6 * unit
    sides = {"a": _Side(ra, len_a, 0, ra.slots, packet),
             "b": _Side(rb, len_b, int(phase * len_a), rb.slots, packet)}
    if max_cycles is None:
        max_cycles = 40 * chars + 5000
    outs = {}
    for who, side in sides.items():
        outs[who] = side.ref.outputs()
        side.d_hist.append(outs[who].d_out)
        side.s_hist.append(outs[who].s_out)
    peer_of = {"a": "b", "b": "a"}
    while True:
        a, b = sides["a"], sides["b"]
        if (a.received >= chars and b.received >= chars) or a.cycle >= max_cycles:
            break
        end_a = a.phase + (a.cycle + 1) * a.cycle_len
        end_b = b.phase + (b.cycle + 1) * b.cycle_len
        who = "a" if end_a <= end_b else "b"
        me, peer = sides[who], sides[peer_of[who]]
        out = outs[who]
        # Inputs: the peer's line at the start of each of my slots of this cycle.
        t0 = me.phase + me.cycle * me.cycle_len
        d_in = s_in = 0
        for j in range(me.slots):
            d, s = peer.level(t0 + j * me.cycle_len // me.slots)
            d_in |= d << j
            s_in |= s << j
        # Host: offer the next character always, read everything.
        if out.rx_valid:
            expect = peer.char(me.received)
            if out.rx_payload == expect:
                me.received += 1
            else:
                me.wrong += 1
        payload = me.char(me.sent)
        if out.tx_ready:
            me.sent += 1
        running = out.state == _RUN
        if running and not me.in_run:
            me.runs += 1
        me.in_run = running
        me.ref.step(d_in=d_in, s_in=s_in, tx_valid=1, tx_payload=payload, rx_ready=1,
                    link_start=1)
        me.cycle += 1
        outs[who] = out = me.ref.outputs()
        me.d_hist.append(out.d_out)
        me.s_hist.append(out.s_out)
        # Forget line history the peer can no longer sample (keep a few cycles).
        if len(me.d_hist) > 4096:
            drop = len(me.d_hist) - 64
            del me.d_hist[:drop], me.s_hist[:drop]
            me.base += drop
    return ClockRun(sent={w: s.sent for w, s in sides.items()},
                    received={w: s.received for w, s in sides.items()},
                    wrong={w: s.wrong for w, s in sides.items()},
                    errors={w: dict(s.ref.errors) for w, s in sides.items()},
                    runs={w: s.runs for w, s in sides.items()},
                    cycles={w: s.cycle for w, s in sides.items()})
