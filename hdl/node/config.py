"""CONFIG registers of the node core, and when ARM takes effect.

A CONFIG record (:class:`~protocol.regs.Config` id, int32 value; docs/node.md "Packets")
acts in the cycle after its last byte (the block holds the decoder's record in a register, so
that nothing from the link's depacketizer reaches the period timer's compares; docs/node.md
"Clock"): it writes one register then; a value out of a register's range is ignored (MODE
≥ 3, TICK 0 or ≥ 2^16, PERIOD and DMP_STEP < 2 or ≥ 2^24, SYNC_WINDOW, COMMIT, STANDSTILL,
STOP_CYCLES and BRAKE_CYCLES ≥ 2^24, STANDSTILL_TICKS and STOP_TRAIL ≥ 2^16, TC_DISCIPLINE
≥ 2^21, DMP not a :class:`~protocol.regs.DmpControl` value).
PRESET and PRIME are strobes to the encoder and the VDC sequencer; DMP is one of three
strobes to the primitive generator's timing (:class:`~hdl.node.dmp_seq.DmpTiming`). Every
register starts at :data:`~protocol.regs.CONFIG_DEFAULTS`.

ARM = 0 disarms at once (safety first). ARM ≠ 0 takes effect at the next period boundary, so
the state at that boundary does not depend on when the CONFIG arrived, and it clears the joint
program's PID integral there: its fine part (``clear_lo``) in the cycle before the boundary,
its coarse part (``clear_hi``) in the boundary's cycle. The joint engine is idle in both when
TICK ≥ the program's cycles + 2 and PERIOD is a multiple of TICK (docs/node.md "Timing").
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.discipline import WORD_BITS as DISCIPLINE_BITS
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.regs import CONFIG_DEFAULTS, MODES, Config, DmpControl

from .decoder import ConfigRecord
from .timer import DisciplineWord

__all__ = ["NodeConfig"]


class NodeConfig(wiring.Component):
    """The CONFIG registers and the ARM sequence (see the module docstring).

    Attributes
    ----------
    config : In(stream.Signature(ConfigRecord, always_ready=True))
        CONFIG records (from :class:`~hdl.node.decoder.PacketDecoder`).
    pre_boundary, boundary : In(1)
        The period timer's last phase and its boundary (:class:`~hdl.node.timer.PeriodTimer`).
    joint_busy : In(1)
        The joint engine runs (the fine integral clear waits for it).
    mode : Out(2)
        Joint program: :data:`~protocol.regs.MODES`.
    tick : Out(16)
        Cycles per control tick.
    timeout, ramp, tau_min, tau_max : Out(32), Out(24), Out(signed(24)), Out(signed(24))
        The watchdog's settings (:class:`~hdl.node.watchdog.Watchdog`).
    period, window, commit : Out(24)
        The period timer's length, its sync window and Comm D's commit phase.
    preset, preset_count : Out(1), Out(signed(32))
        Strobe: load the encoder count.
    prime : Out(1)
        Strobe: CONFIG PRIME (the next VDC run restarts its derivative history).
    arm, disarm : Out(1)
        Strobes to the watchdog: ARM taking effect (at a boundary); ARM = 0 (at once).
    clear_lo, clear_hi : Out(1)
        Strobes: write zero into the joint program's ``ilo_s`` / ``ihi_s`` (the PID integral).
    dmp_step : Out(24)
        CONFIG DMP_STEP: cycles per step of the primitive generator.
    dmp_off, dmp_start, dmp_stop : Out(1)
        Strobes: CONFIG DMP = OFF, START, STOP (:class:`~protocol.regs.DmpControl`).
    stop_cycles, brake_cycles : Out(24)
        The watchdog's safe stop: time limit of the hold before the brake, hold with the brake
        engaged (:mod:`~protocol.safe_stop`).
    standstill, standstill_ticks : Out(24), Out(16)
        The watchdog's standstill rule: threshold (VEL word) and consecutive ticks.
    stop_trail : Out(16)
        The safe stop's trail: how far (counts) the hold's target may trail the count while
        the joint stops (:class:`~hdl.node.ticks.ControlTicks`).
    discipline, discipline_set : Out(DisciplineWord), Out(1)
        CONFIG TC_DISCIPLINE (:mod:`~protocol.discipline`) and its write strobe (the period
        timer clears its loop).
    window_next : Out(24)
        The value ``window`` takes in the next cycle (this cycle's write, or the register).
    pm1_next, pmw_next, pmt_next : Out(signed(26))
        ``PERIOD − 1``, ``PERIOD − SYNC_WINDOW``, ``PERIOD − TICK + 1`` as they stand in the
        next cycle: the period timer's thresholds are these plus its ``adj``. Kept in
        registers; a record's new differences are formed from the decoder's record in the
        cycle before it acts (and registered with it), so a write only selects them.
    """

    config:       In(stream.Signature(ConfigRecord, always_ready=True))
    pre_boundary: In(1)
    boundary:     In(1)
    joint_busy:   In(1)
    mode:         Out(2, init=CONFIG_DEFAULTS[Config.MODE])
    tick:         Out(16, init=CONFIG_DEFAULTS[Config.TICK])
    timeout:      Out(32, init=CONFIG_DEFAULTS[Config.TIMEOUT])
    ramp:         Out(WORD, init=CONFIG_DEFAULTS[Config.RAMP])
    tau_min:      Out(signed(WORD), init=CONFIG_DEFAULTS[Config.TAU_MIN])
    tau_max:      Out(signed(WORD), init=CONFIG_DEFAULTS[Config.TAU_MAX])
    period:       Out(24, init=CONFIG_DEFAULTS[Config.PERIOD])
    window:       Out(24, init=CONFIG_DEFAULTS[Config.SYNC_WINDOW])
    commit:       Out(24, init=CONFIG_DEFAULTS[Config.COMMIT])
    preset:       Out(1)
    preset_count: Out(signed(32))
    prime:        Out(1)
    arm:          Out(1)
    disarm:       Out(1)
    clear_lo:     Out(1)
    clear_hi:     Out(1)
    dmp_step:     Out(24, init=CONFIG_DEFAULTS[Config.DMP_STEP])
    dmp_off:      Out(1)
    dmp_start:    Out(1)
    dmp_stop:     Out(1)
    stop_cycles:  Out(24, init=CONFIG_DEFAULTS[Config.STOP_CYCLES])
    brake_cycles: Out(24, init=CONFIG_DEFAULTS[Config.BRAKE_CYCLES])
    standstill:   Out(WORD, init=CONFIG_DEFAULTS[Config.STANDSTILL])
    standstill_ticks: Out(16, init=CONFIG_DEFAULTS[Config.STANDSTILL_TICKS])
    stop_trail:   Out(16, init=CONFIG_DEFAULTS[Config.STOP_TRAIL])
    discipline:   Out(DisciplineWord)        # reset 0: off (CONFIG_DEFAULTS)
    discipline_set: Out(1)
    window_next:  Out(24)
    pm1_next:     Out(signed(26))
    pmw_next:     Out(signed(26))
    pmt_next:     Out(signed(26))

    def elaborate(self, platform):
        m = Module()
        arm_pending = Signal()          # CONFIG ARM=1 received
        arming      = Signal()          # armed at the coming boundary (integral cleared)
        # The decoder's record, acting a cycle later from this register.
        valid = Signal()
        rec   = Signal.like(self.config.p)
        m.d.sync += [valid.eq(self.config.valid), rec.eq(self.config.p)]
        value = rec.value
        # The writes the period timer's thresholds follow, decoded from the decoder's record
        # and registered with it, and the differences they set (a record's registers are
        # settled when it comes: records are five bytes, so five cycles, apart).
        v_in, id_in = self.config.p.value, self.config.p.id
        we_tick, we_period, we_window, we_disc = (Signal(name=n) for n in
                                                  ("we_tick", "we_period", "we_window",
                                                   "we_disc"))
        ok_tick   = (id_in == Config.TICK) & (v_in != 0) & (v_in < (1 << 16))
        ok_period = (id_in == Config.PERIOD) & (v_in >= 2) & (v_in < (1 << 24))
        ok_window = (id_in == Config.SYNC_WINDOW) & (v_in < (1 << 24))
        m.d.sync += [
            we_tick.eq(self.config.valid & ok_tick),
            we_period.eq(self.config.valid & ok_period),
            we_window.eq(self.config.valid & ok_window),
            we_disc.eq(self.config.valid & (id_in == Config.TC_DISCIPLINE) &
                       (v_in < (1 << DISCIPLINE_BITS))),
        ]
        p0, w0, t0 = (CONFIG_DEFAULTS[r] for r in (Config.PERIOD, Config.SYNC_WINDOW,
                                                   Config.TICK))
        pm1 = Signal(signed(26), init=p0 - 1)
        pmw = Signal(signed(26), init=p0 - w0)
        pmt = Signal(signed(26), init=p0 - t0 + 1)
        new1, neww, newt = (Signal(signed(26), name=n) for n in ("new1", "neww", "newt"))
        v24 = v_in[:24]
        per = Mux(ok_period, v24, self.period)
        m.d.sync += [
            new1.eq(per - 1),
            neww.eq(per - Mux(ok_window, v24, self.window)),
            newt.eq(per - Mux(ok_tick, v_in[:16], self.tick) + 1),
        ]
        touched = we_tick | we_period | we_window
        m.d.comb += [
            self.window_next.eq(Mux(we_window, value[:24], self.window)),
            self.pm1_next.eq(Mux(touched, new1, pm1)),
            self.pmw_next.eq(Mux(touched, neww, pmw)),
            self.pmt_next.eq(Mux(touched, newt, pmt)),
        ]
        m.d.sync += [pm1.eq(self.pm1_next), pmw.eq(self.pmw_next), pmt.eq(self.pmt_next)]
        with m.If(we_tick):
            m.d.sync += self.tick.eq(value)
        with m.If(we_period):
            m.d.sync += self.period.eq(value)
        with m.If(we_window):
            m.d.sync += self.window.eq(value)
        with m.If(we_disc):
            m.d.sync += self.discipline.eq(value)
        m.d.comb += self.discipline_set.eq(we_disc)

        with m.If(valid):
            with m.Switch(rec.id):
                with m.Case(Config.MODE):
                    with m.If(value < len(MODES)):
                        m.d.sync += self.mode.eq(value)
                with m.Case(Config.TIMEOUT):
                    m.d.sync += self.timeout.eq(value)
                with m.Case(Config.RAMP):
                    m.d.sync += self.ramp.eq(value)
                with m.Case(Config.TAU_MIN):
                    m.d.sync += self.tau_min.eq(value)
                with m.Case(Config.TAU_MAX):
                    m.d.sync += self.tau_max.eq(value)
                with m.Case(Config.COMMIT):
                    with m.If(value < (1 << 24)):
                        m.d.sync += self.commit.eq(value)
                with m.Case(Config.ARM):
                    with m.If(value != 0):
                        m.d.sync += arm_pending.eq(1)
                    with m.Else():
                        m.d.comb += self.disarm.eq(1)
                with m.Case(Config.PRESET):
                    m.d.comb += [
                        self.preset.eq(1),
                        self.preset_count.eq(value),
                    ]
                with m.Case(Config.PRIME):
                    m.d.comb += self.prime.eq(1)
                with m.Case(Config.DMP):
                    m.d.comb += [
                        self.dmp_off.eq(value == DmpControl.OFF),
                        self.dmp_start.eq(value == DmpControl.START),
                        self.dmp_stop.eq(value == DmpControl.STOP),
                    ]
                with m.Case(Config.DMP_STEP):
                    with m.If((value >= 2) & (value < (1 << 24))):
                        m.d.sync += self.dmp_step.eq(value)
                with m.Case(Config.STOP_CYCLES):
                    with m.If(value < (1 << 24)):
                        m.d.sync += self.stop_cycles.eq(value)
                with m.Case(Config.BRAKE_CYCLES):
                    with m.If(value < (1 << 24)):
                        m.d.sync += self.brake_cycles.eq(value)
                with m.Case(Config.STANDSTILL):
                    with m.If(value < (1 << WORD)):
                        m.d.sync += self.standstill.eq(value)
                with m.Case(Config.STANDSTILL_TICKS):
                    with m.If(value < (1 << 16)):
                        m.d.sync += self.standstill_ticks.eq(value)
                with m.Case(Config.STOP_TRAIL):
                    with m.If(value < (1 << 16)):
                        m.d.sync += self.stop_trail.eq(value)

        # ARM at the next boundary, the integral cleared in its cycle and the one before;
        # disarming wins over both.
        m.d.comb += [
            self.clear_lo.eq(self.pre_boundary & arm_pending & ~self.joint_busy),
            self.clear_hi.eq(self.boundary & arming),
            self.arm.eq(self.clear_hi & ~self.disarm),
        ]
        with m.If(self.disarm):
            m.d.sync += [
                arm_pending.eq(0),
                arming.eq(0),
            ]
        with m.Elif(self.clear_lo):
            m.d.sync += [
                arm_pending.eq(0),
                arming.eq(1),
            ]
        with m.Elif(self.clear_hi):
            m.d.sync += arming.eq(0)
        return m
