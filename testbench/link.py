"""Bus-functional models of the SpaceWire-like link, for Amaranth testbenches.

* :class:`FaultyLine` — one direction of a data-strobe line with fault injection (cut, stuck,
  bit flips), and :func:`apply_line_faults`, its Python twin;
* :class:`CodecPair` — two codecs back to back through two faulty lines;
  :class:`PairBench` drives one cycle by cycle from queues, with faults and a log;
* :class:`LinePeer` — a scripted far end at line level (tokens → D/S bits, NULLs between,
  any bit rate), independent of the gateware and of its reference; :func:`token_bits`;
* :class:`LineMonitor` — decodes a D/S line into timestamped tokens, checking data-strobe
  encoding and parity; counts parity errors, logs transmitter resets;
* :class:`PeerBench` — one gateware codec against a :class:`LinePeer`, with the start-up
  handshake (:meth:`PeerBench.bring_up`);
* :class:`RandomHost`, :func:`drive_codec_inputs`, :func:`read_codec_outputs`,
  :func:`assert_outputs_equal` — seeded random host traffic and the lock-step comparison of a
  gateware codec with its bit-exact reference (:mod:`mrm_cosim.hdl.link.codec_ref`).

ECSS-E-ST-50-12C is the standard behind the characters (§7) and the link states (§8.5).
docs/testbenches.md shows them at work.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.protocol.link import ERROR_CLASSES

from .sim import run_simulation

__all__ = ["ERROR_CLASSES", "FaultyLine", "CodecPair", "read_codec_outputs",
           "assert_outputs_equal", "apply_line_faults", "RandomHost", "drive_codec_inputs",
           "token_bits", "LinePeer", "LineMonitor", "PeerBench", "PairBench"]


class FaultyLine(wiring.Component):
    """One direction of a data-strobe line with fault injection, purely combinational.

    Each line sample is ``((x & ~clear) | set) ^ flip`` per slot: clear both lines to cut the
    wire, set or clear one to make it stuck, flip a slot for a single bit error.
    """

    def __init__(self, slots: int):
        self.slots = slots
        super().__init__({
            "d_in":    In(slots), "s_in":    In(slots),
            "d_out":   Out(slots), "s_out":  Out(slots),
            "clear_d": In(slots), "clear_s": In(slots),
            "set_d":   In(slots), "set_s":   In(slots),
            "flip_d":  In(slots), "flip_s":  In(slots),
        })

    def elaborate(self, platform):
        m = Module()
        m.d.comb += [
            self.d_out.eq(((self.d_in & ~self.clear_d) | self.set_d) ^ self.flip_d),
            self.s_out.eq(((self.s_in & ~self.clear_s) | self.set_s) ^ self.flip_s),
        ]
        return m


class CodecPair(Elaboratable):
    """Two codecs ``a`` and ``b`` wired back to back through ``ab`` and ``ba`` faulty lines."""

    def __init__(self, **codec_args):
        self.a = Codec(**codec_args)
        self.b = Codec(**codec_args)
        self.ab = FaultyLine(self.a.slots)
        self.ba = FaultyLine(self.a.slots)

    def elaborate(self, platform):
        m = Module()
        m.submodules.a = self.a
        m.submodules.b = self.b
        m.submodules.ab = self.ab
        m.submodules.ba = self.ba
        for src, line, dst in ((self.a, self.ab, self.b), (self.b, self.ba, self.a)):
            m.d.comb += [
                line.d_in.eq(src.d_out),
                line.s_in.eq(src.s_out),
                dst.d_in.eq(line.d_out),
                dst.s_in.eq(line.s_out),
            ]
        return m


# -- Lock-step comparison of a gateware codec pair with the Python reference -----------------

def read_codec_outputs(ctx, codec):
    """The gateware codec's outputs this cycle, in the shape of ``CodecOutputs``."""
    from mrm_cosim.hdl.link.codec_ref import CodecOutputs
    errors = ctx.get(codec.errors)
    return CodecOutputs(
        tx_ready=ctx.get(codec.tx.ready),
        rx_valid=ctx.get(codec.rx.valid),
        rx_payload=ctx.get(codec.rx.payload.as_value()),
        tick_out=ctx.get(codec.tick_out),
        time_out=ctx.get(codec.time_out),
        running=ctx.get(codec.running),
        state=ctx.get(codec.state).value,
        errors={name: getattr(errors, name) for name in ERROR_CLASSES},
        tx_credit=ctx.get(codec.tx_credit),
        rx_credit=ctx.get(codec.rx_credit),
        d_out=ctx.get(codec.d_out),
        s_out=ctx.get(codec.s_out),
    )


def assert_outputs_equal(rtl, ref, *, cycle, who):
    """Compare two ``CodecOutputs``; ``rx_payload`` only matters while ``rx_valid``."""
    if not rtl.rx_valid:
        rtl = rtl._replace(rx_payload=0)
        ref = ref._replace(rx_payload=0)
    if rtl != ref:
        diff = {k: (getattr(rtl, k), getattr(ref, k)) for k in rtl._fields
                if getattr(rtl, k) != getattr(ref, k)}
        raise AssertionError(f"cycle {cycle}, codec {who}: RTL != reference (rtl, ref): {diff}")


def apply_line_faults(value, fault):
    """Python twin of :class:`FaultyLine` for one line: ``fault = (clear, set, flip)``."""
    clear, set_, flip = fault
    return ((value & ~clear) | set_) ^ flip


class RandomHost:
    """Seeded random host traffic for one codec: packets with gaps, rx back-pressure, ticks.

    Per cycle call :meth:`inputs` (values to drive), then :meth:`observe` with that cycle's
    outputs. ``sent`` and ``received`` log the N-chars (Char values) that crossed the host
    streams; ``ticks`` the time-code values delivered.
    """

    def __init__(self, rng, *, p_offer=0.6, p_stall=0.02, p_unstall=0.05, p_tick=0.004,
                 max_len=20, p_eep=0.1):
        from mrm_cosim.hdl.link.codec_ref import char_value
        self._char_value = char_value
        self.rng = rng
        self.p_offer, self.p_stall, self.p_unstall = p_offer, p_stall, p_unstall
        self.p_tick, self.max_len, self.p_eep = p_tick, max_len, p_eep
        self.queue = []
        self.offering = None
        self.rx_ready = 1
        self.sent, self.received, self.ticks = [], [], []
        self._tick = 0

    def _next_char(self):
        if not self.queue:
            n = int(self.rng.integers(0, self.max_len + 1))
            data = [self._char_value(0, int(x)) for x in self.rng.integers(0, 256, n)]
            end = 2 if self.rng.random() < self.p_eep else 1
            self.queue = data + [self._char_value(end)]
        return self.queue.pop(0)

    def inputs(self):
        rng = self.rng
        if self.offering is None and rng.random() < self.p_offer:
            self.offering = self._next_char()
        if self.rx_ready and rng.random() < self.p_stall:
            self.rx_ready = 0
        elif not self.rx_ready and rng.random() < self.p_unstall:
            self.rx_ready = 1
        self._tick = int(rng.random() < self.p_tick)
        return {
            "tx_valid": int(self.offering is not None),
            "tx_payload": self.offering if self.offering is not None else 0,
            "rx_ready": self.rx_ready,
            "tick_in": self._tick,
            "time_in": int(rng.integers(0, 256)),
        }

    def observe(self, outputs):
        if self.offering is not None and outputs.tx_ready:
            self.sent.append(self.offering)
            self.offering = None
        if self.rx_ready and outputs.rx_valid:
            self.received.append(outputs.rx_payload)
        if outputs.tick_out:
            self.ticks.append(outputs.time_out)


def drive_codec_inputs(ctx, codec, values):
    """Drive a codec's host inputs from a dict as :meth:`RandomHost.inputs` returns."""
    ctx.set(codec.tx.valid, values["tx_valid"])
    ctx.set(codec.tx.payload.as_value(), values["tx_payload"])
    ctx.set(codec.rx.ready, values["rx_ready"])
    ctx.set(codec.tick_in, values["tick_in"])
    ctx.set(codec.time_in, values["time_in"])


# -- Line-level bus-functional models (independent of the gateware and of CodecRef) ----------

_CODES = {"FCT": (0, 0), "EOP": (0, 1), "EEP": (1, 0), "ESC": (1, 1)}   # (C0, C1), C0 sent first


def token_bits(tokens, par=0):
    """Line bits of a token sequence with odd parity, and the parity state after it.

    Tokens: ``("FCT",)``, ``("EOP",)``, ``("EEP",)``, ``("ESC",)``, ``("NULL",)``,
    ``("DATA", byte)``, ``("TIME", byte)``. A token may end with ``"bad-parity"`` to send its
    (first) parity bit inverted, or ``"corrupt"`` to send its last character with the first
    data/control bit inverted after the parity was worked out (a bit error on the line, which
    the *next* character's parity exposes). ``par`` is the XOR of the previous character's
    data bits.
    """
    bits = []
    for token in tokens:
        kind, args = token[0], [a for a in token[1:] if a not in ("bad-parity", "corrupt")]
        bad = "bad-parity" in token[1:]
        corrupt = "corrupt" in token[1:]
        chars = {"NULL": [("ESC",), ("FCT",)], "TIME": [("ESC",), ("DATA", *args)]}.get(
            kind, [(kind, *args)])
        for n, (ck, *cargs) in enumerate(chars):
            flag = 0 if ck == "DATA" else 1
            p = 1 ^ par ^ flag ^ (1 if bad and n == 0 else 0)
            if ck == "DATA":
                payload = [(cargs[0] >> i) & 1 for i in range(8)]
            else:
                payload = list(_CODES[ck])
            par = sum(payload) & 1
            if corrupt and n == len(chars) - 1:
                payload = [payload[0] ^ 1] + payload[1:]
            bits += [p, flag] + payload
    return bits, par


class LinePeer:
    """A scripted far end: sends queued tokens at ``div`` slots per bit, NULLs in between.

    ``silent`` keeps the line still (both lines low until the first bit). Call :meth:`cycle`
    once per clock for the ``(d, s)`` words to drive.
    """

    def __init__(self, slots, div, *, silent=True):
        self.slots, self.div = slots, div
        self.silent = silent
        self.bits = []
        self.par = 0
        self.d = self.s = 0
        self.left = 0
        self.fill_nulls = True

    def send(self, *tokens):
        bits, self.par = token_bits(tokens, self.par)
        self.bits += bits

    def cycle(self):
        d_word = s_word = 0
        for i in range(self.slots):
            if self.left == 0 and not self.silent:
                if not self.bits and self.fill_nulls:
                    self.send(("NULL",))
                if self.bits:
                    bit = self.bits.pop(0)
                    if bit == self.d:
                        self.s ^= 1
                    self.d = bit
                    self.left = self.div
            if self.left:
                self.left -= 1
            d_word |= self.d << i
            s_word |= self.s << i
        return d_word, s_word


class LineMonitor:
    """Decode a codec's line output into tokens, checking DS encoding and parity.

    Feed :meth:`cycle` the ``(d, s)`` words; ``tokens`` collects ``(cycle, token)`` from the
    first NULL on, with NULL and time-codes merged as in :func:`token_bits`; ``parity_errors``
    counts parity failures. ``bit_slots`` are the slot indices (from the start) of every bit,
    ``changes`` the ``(cycle, slot)`` of every change on either line. A drop of both lines from
    1 1 to 0 0 in one slot (a transmitter reset that is not a controlled one; the project's
    codec lowers S first, then D, since 25 Nov) restarts the framing and is logged in ``resets``.
    """

    def __init__(self, slots):
        self.slots = slots
        self.prev = (0, 0)
        self.t = 0
        self.bits = []
        self.bit_slots = []
        self.changes = []           # (cycle, slot) of every change on D or S
        self.resets = []            # cycles where the transmitter dropped both lines
        self.tokens = []
        self.parity_errors = 0
        self._pos = None        # index into self.bits of the next character, once framed
        self._search_from = 0   # where the search for the first NULL resumes
        self._esc = False
        self._par = 0
        self._cycle = 0

    def cycle(self, d_word, s_word):
        for i in range(self.slots):
            cur = ((d_word >> i) & 1, (s_word >> i) & 1)
            if cur == (0, 0) and self.prev == (1, 1):
                # The transmitter was reset (both lines dropped): framing starts over.
                self.bits, self._pos, self._esc, self._par = [], None, False, 0
                self._search_from = 0
                self.resets.append(self._cycle)
                self.changes.append((self._cycle, i))
                self.prev = cur
                self.t += 1
                continue
            assert not (cur[0] != self.prev[0] and cur[1] != self.prev[1]), \
                f"D and S changed together at slot {self.t}"
            if cur != self.prev:
                self.changes.append((self._cycle, i))
            if cur[0] ^ cur[1] != self.prev[0] ^ self.prev[1]:
                self.bits.append(cur[0])
                self.bit_slots.append(self.t)
            self.prev = cur
            self.t += 1
        self._frame()
        self._cycle += 1

    def _frame(self):
        b = self.bits
        if self._pos is None:
            for k in range(self._search_from, len(b) - 7):
                if b[k + 1:k + 8] == [1, 1, 1, 0, 1, 0, 0]:
                    self._pos, self._par = k + 8, 0
                    self.tokens.append((self._cycle, ("NULL",)))
                    break
            else:
                self._search_from = max(self._search_from, len(b) - 7)
            return
        while True:
            k = self._pos
            if len(b) < k + 2:
                return
            p, flag = b[k], b[k + 1]
            n = 2 if flag else 8
            if len(b) < k + 2 + n:
                return
            if (self._par ^ p ^ flag) != 1:
                # As a receiver would: count it and look for the next NULL (the transmitter
                # restarts with NULLs after a reset that did not drop both lines together).
                self.parity_errors += 1
                self._pos, self._esc, self._search_from = None, False, k
                return self._frame()
            payload = b[k + 2:k + 2 + n]
            self._par = sum(payload) & 1
            self._pos = k + 2 + n
            if flag:
                code = {v: name for name, v in _CODES.items()}[tuple(payload)]
                if self._esc:
                    self._esc = False
                    self.tokens.append((self._cycle, ("NULL",) if code == "FCT"
                                        else ("ESC", code)))
                elif code == "ESC":
                    self._esc = True
                else:
                    self.tokens.append((self._cycle, (code,)))
            else:
                value = sum(bit << i for i, bit in enumerate(payload))
                self.tokens.append((self._cycle, ("TIME" if self._esc else "DATA", value)))
                self._esc = False


class PeerBench:
    """One gateware codec (``dut``) against a scripted :class:`LinePeer`.

    Drive it from a testbench with :meth:`cycle` (one clock: line in from the peer, line out
    into ``monitor``, received N-chars into ``received`` while ``rx_ready``) and :meth:`bring_up`
    (the start-up handshake from the peer's side, ending with the DUT in Run).

    The scripted peer grants the credit its script sends, not what a codec like the DUT grants
    at rest, so the DUT's credit audit is off unless ``credit_audit`` is given.
    """

    def __init__(self, *, peer_div=None, **params):
        params.setdefault("credit_audit", 0)
        self.dut = Codec(**params)
        self.peer = LinePeer(self.dut.slots, peer_div or self.dut.start_div)
        self.monitor = LineMonitor(self.dut.slots)
        self.received = []
        self.rx_ready = 1
        self.cycles = 0

    async def cycle(self, ctx):
        dut = self.dut
        d, s = self.peer.cycle()
        ctx.set(dut.d_in, d)
        ctx.set(dut.s_in, s)
        ctx.set(dut.rx.ready, self.rx_ready)
        self.monitor.cycle(ctx.get(dut.d_out), ctx.get(dut.s_out))
        if self.rx_ready and ctx.get(dut.rx.valid):
            self.received.append(ctx.get(dut.rx.payload.as_value()))
        await ctx.tick()
        self.cycles += 1

    async def run(self, ctx, n):
        for _ in range(n):
            await self.cycle(ctx)

    async def until(self, ctx, condition, limit=5000):
        """Clock until ``condition()`` holds (checked before each cycle); fail after ``limit``."""
        for _ in range(limit):
            if condition():
                return
            await self.cycle(ctx)
        raise AssertionError(f"condition not reached within {limit} cycles")

    async def bring_up(self, ctx, *, fast_div=None):
        """Handshake to Run: NULLs once the DUT has started, an FCT once it sends FCTs; then
        the peer sends at ``fast_div`` slots per bit (default: the DUT's run rate)."""
        from mrm_cosim.hdl.link.chars import LinkState
        dut = self.dut
        ctx.set(dut.link_start, 1)
        await self.until(ctx, lambda: ctx.get(dut.state) == LinkState.STARTED)
        self.peer.silent = False
        await self.until(ctx, lambda: any(t == ("FCT",) for _, t in self.monitor.tokens))
        self.peer.send(("FCT",))
        await self.until(ctx, lambda: ctx.get(dut.running))
        self.peer.div = fast_div or dut.run_div_init

    def errors(self, ctx):
        counts = ctx.get(self.dut.errors)
        return {name: getattr(counts, name) for name in ERROR_CLASSES}


class PairBench:
    """A :class:`CodecPair` driven cycle by cycle from queues, with line faults and a log.

    ``tx[who]`` are the N-chars (Char values) each host still has to send, offered back to back;
    ``sent[who]`` those the codec took, ``received[who]`` those it delivered while
    ``rx_ready[who]``; ``states[who]`` is a list of (first cycle, LinkState) per state
    entered; ``ticks[who]`` the (cycle, time value) of each tick_out. ``faults`` maps "ab"/"ba"
    to ``((clear, set, flip) for D, (clear, set, flip) for S)`` applied from the next cycle.
    """

    def __init__(self, **params):
        self.pair = CodecPair(**params)
        self.codecs = {"a": self.pair.a, "b": self.pair.b}
        self.lines = {"ab": self.pair.ab, "ba": self.pair.ba}
        self.tx = {"a": [], "b": []}
        self.sent = {"a": [], "b": []}
        self.received = {"a": [], "b": []}
        self.rx_ready = {"a": 1, "b": 1}
        self.states = {"a": [], "b": []}
        self.ticks = {"a": [], "b": []}
        self.faults = {}
        self.cycles = 0

    def state(self, ctx, who):
        return ctx.get(self.codecs[who].state)

    async def cycle(self, ctx, *, tick=None):
        """One clock. ``tick`` = (who, value) strobes tick_in on that codec this cycle."""
        self.apply_faults(ctx)
        taken = {}
        for who, codec in self.codecs.items():
            ctx.set(codec.link_start, 1)
            ctx.set(codec.tx.valid, int(bool(self.tx[who])))
            if self.tx[who]:
                ctx.set(codec.tx.payload.as_value(), self.tx[who][0])
            ctx.set(codec.rx.ready, self.rx_ready[who])
            ctx.set(codec.tick_in, int(tick is not None and tick[0] == who))
            if tick is not None and tick[0] == who:
                ctx.set(codec.time_in, tick[1])
            state = ctx.get(codec.state)
            if not self.states[who] or self.states[who][-1][1] != state:
                self.states[who].append((self.cycles, state))
            taken[who] = bool(self.tx[who]) and ctx.get(codec.tx.ready)
            if self.rx_ready[who] and ctx.get(codec.rx.valid):
                self.received[who].append(ctx.get(codec.rx.payload.as_value()))
            if ctx.get(codec.tick_out):
                self.ticks[who].append((self.cycles, ctx.get(codec.time_out)))
        for who, took in taken.items():
            if took:
                self.sent[who].append(self.tx[who].pop(0))
        await ctx.tick()
        self.cycles += 1

    def apply_faults(self, ctx):
        """Drive ``faults`` onto the lines now (``cycle`` does it too)."""
        for key, line in self.lines.items():
            (cd, sd, fd), (cs, ss, fs) = self.faults.get(key, ((0, 0, 0), (0, 0, 0)))
            ctx.set(line.clear_d, cd)
            ctx.set(line.set_d, sd)
            ctx.set(line.flip_d, fd)
            ctx.set(line.clear_s, cs)
            ctx.set(line.set_s, ss)
            ctx.set(line.flip_s, fs)

    async def run(self, ctx, n):
        for _ in range(n):
            await self.cycle(ctx)

    async def until(self, ctx, condition, limit=5000):
        for _ in range(limit):
            if condition():
                return
            await self.cycle(ctx)
        raise AssertionError(f"condition not reached within {limit} cycles")

    async def bring_up(self, ctx, limit=5000):
        await self.until(ctx, lambda: ctx.get(self.pair.a.running) and
                         ctx.get(self.pair.b.running), limit)

    def errors(self, ctx, who):
        counts = ctx.get(self.codecs[who].errors)
        return {name: getattr(counts, name) for name in ERROR_CLASSES}

    def simulate(self, testbench, name):
        sim = Simulator(self.pair)
        sim.add_clock(20e-9)
        sim.add_testbench(testbench)
        run_simulation(sim, name)


def assert_link_state(ctx, codec, expected):
    """Fail unless ``codec``'s link state machine is in ``expected`` (a ``LinkState`` member
    or its name, e.g. ``"RUN"``); the message names both states."""
    from mrm_cosim.hdl.link.chars import LinkState
    want = LinkState[expected] if isinstance(expected, str) else LinkState(expected)
    got = LinkState(ctx.get(codec.state))
    if got != want:
        raise AssertionError(f"link state is {got.name}, expected {want.name}")


def assert_error_counts(ctx, codec, **expected):
    """Fail unless ``codec``'s saturating error counters match ``expected`` (by class name:
    ``disconnect``, ``parity``, ``escape``, ...); classes not named must be zero."""
    unknown = set(expected) - set(ERROR_CLASSES)
    if unknown:
        raise ValueError(f"unknown error classes {sorted(unknown)}; known: {ERROR_CLASSES}")
    counts = ctx.get(codec.errors)
    got = {name: int(getattr(counts, name)) for name in ERROR_CLASSES}
    want = {name: expected.get(name, 0) for name in ERROR_CLASSES}
    if got != want:
        raise AssertionError(f"error counters are {got}, expected {want}")
