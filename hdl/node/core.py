"""The node compute core: packets in, replies out, encoder in, torque out.

::

    rx beats ──► packet decoder ──┬─ Comm B words ──► VDC engine ─ F_a, F_b ─┐
    (LinkNode)                    ├─ Comm D ─ g_C ──►   (regfile)            │
                                  │        └ τ_D, q_d0, q̇_d0, q̈_d0 ─► D regs ┼─► joint engine
                                  ├─ PARAM ──► VDC / joint register files    │   every tick
                                  └─ CONFIG ─► mode, tick, limits, arm, …    │       │ τ
    timer (phase 0) ─► snapshot (count, q̇, τ, status, …) ─► CORDIC ─► q̇, cos q, sin q ─► VDC
    encoder A/B ──► decoder, velocity ──────────────────────────────────────►  limits, watchdog
    tx beats ◄── reply: Comm A (snapshot, status) / Comm C (F_a, F_b once ready) ─► torque

Behaviour (the transaction-level reference is :class:`~hdl.node.core_ref.NodeModel`). What the
node does, and when, depends on packet contents and its own period timer only, never on the
cycle a packet or time-code arrived (docs/node.md "Timing"):

* A period timer free-runs from reset (CONFIG PERIOD, 50,000 cycles). Its boundary (phase 0)
  snapshots the encoder count and velocity, the torque, status, encoder errors and counters
  (everything Comm A reports), runs the CORDIC and restarts the control ticks. Its result and
  the velocity go into the VDC's registers.
* The time-code (``period_start``) is monitored: one arriving at a phase outside
  ``[0, SYNC_WINDOW)`` makes its own cycle a boundary (re-synchronisation), counted while
  armed (``sync_errors`` in Comm A). Its value is echoed in the replies.
* A Comm B of 40 bytes writes its 13 words into the VDC's registers as they arrive, then starts
  the VDC (from ``"first"`` after reset, arming, a trip, a PRIME config or flag; else
  ``"main"``). A Comm C request is answered as soon as the VDC has its forces (MARK).
* A Comm D of 40 bytes writes ``g_C`` into the VDC's registers; ``τ_D, q_d0, q̇_d0, q̈_d0``
  (all four at once) take effect at phase COMMIT while armed (one arriving at or after COMMIT
  waits for the next commit point and is counted, ``late_d``), at its last byte while disarmed.
* ARM takes effect at the next boundary and clears the PID integral; disarming is immediate.
* Every ``tick`` cycles from the boundary the encoder velocity is sampled and the joint engine
  runs with the latched count, velocity, Comm D values and ``t_next`` (from the boundary); its
  torque goes through the :class:`~hdl.node.watchdog.Watchdog`. A tick that finds the joint
  engine busy is skipped and counted (``overruns``).
* Words arrive over the byte stream; a word for a busy engine waits (``rx.ready`` low).
* Every payload byte of a CONFIG or PARAM packet goes, in arrival order, into a running
  CRC-16/CCITT-FALSE (the link's, :mod:`hdl.link.crc`, from 0xFFFF at reset) and every such
  packet into a 16-bit count (modulo 2^16); nothing but reset clears them. A Comm A reply
  carries both as they stood when its request arrived, so the master can check that the node
  took every upload (docs/node.md "Upload check").
* The link's health goes into every Comm A too, as it stands when the request arrives: the
  error totals of the upstream and downstream codecs (the five classes of
  :class:`~hdl.link.chars.ErrorCounts` summed, saturating), the frames the depacketizer dropped
  (CRC, length, EEP) and the packets the router discarded (docs/node.md "Link health").
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.chars import ErrorCounts, saturating_sum
from mrm_cosim.hdl.link.crc import crc16_next
from mrm_cosim.hdl.link.packet import Beat, PacketType, RxStats
from mrm_cosim.protocol.crc import CRC16_INIT
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.isa import IO_BASE
from mrm_cosim.protocol.joint_program import INPUTS as JOINT_INPUTS
from mrm_cosim.protocol.link import ERROR_CLASSES
from mrm_cosim.protocol.regs import (COMM_B_WORDS, CONFIG_DEFAULTS, MODES, PAYLOAD, RX_DROPS,
                                     Bank, Config)
from mrm_cosim.protocol.regs import NodeEvent as Ev

from .encoder import QuadratureEncoder
from .joint import JointUnit
from .trig import SinCos
from .vdc import VdcUnit
from .watchdog import Watchdog

__all__ = ["NodeCore"]

_TIME_MAX = (1 << 23) - 1


class NodeCore(wiring.Component):
    """One module's compute core (see the module docstring).

    Parameters
    ----------
    encoder : EncoderParams
        Encoder interface parameters (resolution, clock, filter, windows).

    Attributes
    ----------
    rx : In(stream.Signature(Beat))
        Packets for this node (from :class:`~hdl.link.node.LinkNode` ``rx``).
    tx : Out(stream.Signature(Beat))
        Replies (to ``LinkNode.tx``).
    period_start : In(1)
        The time-code strobe (monitored; re-synchronises the timer outside the window).
    period : In(8)
        The time-code value, echoed in the replies.
    enc_a, enc_b : In(1)
        Encoder lines.
    torque : Out(signed(24))
        Torque command (FORCE word: N·m · 2^13).
    status : Out(16)
        :class:`~hdl.node.regs.Status` bits.
    count : Out(signed(32))
        Live encoder count.
    velocity : Out(signed(24))
        Live velocity estimate (VEL word).
    up_errors, down_errors : In(ErrorCounts)
        The link codecs' error counters (from :class:`~hdl.link.node.LinkNode`).
    rx_stats : In(RxStats)
        The depacketizer's counters.
    dropped : In(16)
        The router's discarded packets.
    events : Out(16)
        Observation port: one-cycle :class:`~hdl.node.regs.NodeEvent` strobes (boundary,
        packets taken, VDC start / MARK / end, replies leaving, Comm D commit). Test points
        only: combinational copies of existing signals, nothing in the node reads them.
    """

    rx:           In(stream.Signature(Beat))
    tx:           Out(stream.Signature(Beat))
    period_start: In(1)
    period:       In(8)
    enc_a:        In(1)
    enc_b:        In(1)
    torque:       Out(signed(WORD))
    status:       Out(16)
    count:        Out(signed(32))
    velocity:     Out(signed(WORD))
    up_errors:    In(ErrorCounts)
    down_errors:  In(ErrorCounts)
    rx_stats:     In(RxStats)
    dropped:      In(16)
    events:       Out(16)

    def __init__(self, *, encoder: EncoderParams | None = None):
        self._enc = encoder or EncoderParams()
        super().__init__()

    @property
    def encoder_params(self) -> EncoderParams:
        return self._enc

    def elaborate(self, platform):
        m = Module()
        m.submodules.encoder = enc = QuadratureEncoder(self._enc)
        m.submodules.trig = trig = SinCos(counts_per_rev=self._enc.counts_per_rev)
        m.submodules.vdc = vdc = VdcUnit()
        m.submodules.joint = joint = JointUnit()
        m.submodules.watchdog = wd = Watchdog()
        vmc, jmc = vdc.microcode, joint.microcode

        m.d.comb += [
            enc.a.eq(self.enc_a),
            enc.b.eq(self.enc_b),
            self.count.eq(enc.count),
            self.velocity.eq(enc.velocity),
        ]

        # --- configuration ------------------------------------------------------------------
        cfg_mode    = Signal(2, init=CONFIG_DEFAULTS[Config.MODE])
        cfg_tick    = Signal(16, init=CONFIG_DEFAULTS[Config.TICK])
        cfg_timeout = Signal(32, init=CONFIG_DEFAULTS[Config.TIMEOUT])
        cfg_ramp    = Signal(WORD, init=CONFIG_DEFAULTS[Config.RAMP])
        cfg_tmin    = Signal(signed(WORD), init=CONFIG_DEFAULTS[Config.TAU_MIN])
        cfg_tmax    = Signal(signed(WORD), init=CONFIG_DEFAULTS[Config.TAU_MAX])
        cfg_period  = Signal(24, init=CONFIG_DEFAULTS[Config.PERIOD])
        cfg_window  = Signal(24, init=CONFIG_DEFAULTS[Config.SYNC_WINDOW])
        cfg_commit  = Signal(24, init=CONFIG_DEFAULTS[Config.COMMIT])
        prime       = Signal(init=1)
        arm         = Signal()          # the ARM taking effect (at a period boundary)
        arm_pending = Signal()          # CONFIG ARM=1 received
        arming      = Signal()          # armed at the coming boundary (integral cleared)
        disarm      = Signal()
        m.d.comb += [
            wd.timeout.eq(cfg_timeout),
            wd.ramp.eq(cfg_ramp),
            wd.tau_min.eq(cfg_tmin),
            wd.tau_max.eq(cfg_tmax),
            wd.arm.eq(arm),
            wd.disarm.eq(disarm),
            self.torque.eq(wd.torque),
        ]

        # --- period timer: boundary (phase 0) = snapshot, CORDIC, ARM; time-code monitor ------
        # The timer free-runs from reset; a time-code arriving at a phase outside
        # [0, SYNC_WINDOW) makes its own cycle a boundary (re-synchronisation), counted while
        # armed. Nothing here depends on when a packet arrived, only on what it said.
        phase       = Signal(24)
        boundary    = Signal()
        resync      = Signal()
        pre_bound   = Signal()
        tt          = Signal(24)
        sync_errors = Signal(16)
        m.d.comb += [
            resync.eq(self.period_start & (phase >= cfg_window)),
            boundary.eq((phase == 0) | resync),
            pre_bound.eq(phase == cfg_period - 1),
            tt.eq(Mux(boundary, 0, phase)),
        ]
        with m.If(boundary):
            m.d.sync += phase.eq(1)
        with m.Elif(phase >= cfg_period - 1):
            m.d.sync += phase.eq(0)
        with m.Else():
            m.d.sync += phase.eq(phase + 1)
        with m.If(resync & wd.armed & (sync_errors != 0xFFFF)):
            m.d.sync += sync_errors.eq(sync_errors + 1)

        snap_count = Signal(signed(32))
        snap_qd    = Signal(signed(WORD))
        vdc_fresh  = Signal()
        with m.If(boundary):
            m.d.sync += [
                snap_count.eq(enc.count),
                snap_qd.eq(enc.velocity),
                vdc_fresh.eq(0),
            ]
        m.d.comb += [
            trig.start.eq(boundary),
            trig.count.eq(enc.count),
        ]
        sw_pending = Signal()
        sw_idx     = Signal(2)
        sw_cos     = Signal(signed(WORD))
        sw_sin     = Signal(signed(WORD))
        with m.If(trig.done):
            m.d.sync += [
                sw_pending.eq(1),
                sw_idx.eq(0),
                sw_cos.eq(trig.cos),
                sw_sin.eq(trig.sin),
            ]

        # --- host ports: snapshot writer first, then the packet decoder's pending word --------
        pw_valid = Signal()
        pw_bank  = Signal()
        pw_addr  = Signal(9)
        pw_data  = Signal(signed(WORD))
        sw_addr  = Array([C(vmc.addr("qd"), 9), C(vmc.addr("cq"), 9), C(vmc.addr("sq"), 9),
                          C(0, 9)])
        sw_data  = Array([snap_qd, sw_cos, sw_sin, C(0, WORD)])
        with m.If(sw_pending & ~vdc.busy):
            m.d.comb += [
                vdc.host_addr.eq(sw_addr[sw_idx]),
                vdc.host_wdata.eq(sw_data[sw_idx]),
                vdc.host_we.eq(1),
            ]
            m.d.sync += sw_idx.eq(sw_idx + 1)
            with m.If(sw_idx == 2):
                m.d.sync += sw_pending.eq(0)
        with m.Elif(pw_valid & (pw_bank == Bank.VDC) & ~vdc.busy):
            m.d.comb += [
                vdc.host_addr.eq(pw_addr),
                vdc.host_wdata.eq(pw_data),
                vdc.host_we.eq(1),
            ]
            m.d.sync += pw_valid.eq(0)
        # ARM clears the PID integral: its fine part in the cycle before the boundary, its
        # coarse part in the boundary's cycle (the engine is idle in both when TICK ≥ the
        # program's cycles + 2 and PERIOD is a multiple of TICK; see docs/node.md).
        clr_lo = Signal()
        clr_hi = Signal()
        m.d.comb += [
            clr_lo.eq(pre_bound & arm_pending & ~joint.busy),
            clr_hi.eq(boundary & arming),
        ]
        with m.If(clr_lo | clr_hi):
            m.d.comb += [
                joint.host_addr.eq(Mux(clr_lo, jmc.addr("ilo_s"), jmc.addr("ihi_s"))),
                joint.host_wdata.eq(0),
                joint.host_we.eq(1),
            ]
        with m.Elif(pw_valid & (pw_bank == Bank.JOINT) & ~joint.busy):
            m.d.comb += [
                joint.host_addr.eq(pw_addr),
                joint.host_wdata.eq(pw_data),
                joint.host_we.eq(1),
            ]
            m.d.sync += pw_valid.eq(0)

        # --- packet decoder ------------------------------------------------------------------
        vdc_go    = Signal()
        vdc_wait  = Signal()
        reply_a   = Signal()
        reply_c   = Signal()
        seq_a     = Signal(8)
        seq_c     = Signal(8)
        beat   = self.rx.p
        ptype  = beat.header.type
        taken  = Signal()
        pos    = Signal(range(256))
        wacc   = Signal(WORD)
        wj     = Signal(range(3))
        wk     = Signal(range(256))
        word   = Signal(signed(WORD))
        wdone  = Signal()
        cfg_j  = Signal(range(5))
        cfg_id = Signal(8)
        cfg_v  = Signal(24)
        par_bank = Signal()
        par_addr = Signal(16)
        packet_event = Signal()
        d_words  = [Signal(signed(WORD), name=f"d_{n}") for n in ("tau", "qd0", "vd0", "ad0")]
        d_shadow = [Signal(signed(WORD), name=f"ds_{n}") for n in ("tau", "qd0", "vd0", "ad0")]
        d_next   = [Signal(signed(WORD), name=f"dn_{n}") for n in ("tau", "qd0", "vd0", "ad0")]
        d_pending = Signal()
        d_arrive  = Signal()
        late_d    = Signal(16)
        b_addr = Array(C(vmc.addr(n), 9) for n in COMM_B_WORDS)
        g_addr = Array(C(vmc.addr(f"gC{k}"), 9) for k in range(3))

        m.d.comb += [
            self.rx.ready.eq(~pw_valid),
            taken.eq(self.rx.valid & self.rx.ready),
            word.eq(Cat(wacc[8:], beat.data)),
        ]
        is_b = ptype == PacketType.COMM_B
        is_d = ptype == PacketType.COMM_D
        is_p = ptype == PacketType.PARAM
        is_c = ptype == PacketType.CONFIG
        in_words = (is_b | is_d | (is_p & (pos >= 3)))
        m.d.comb += wdone.eq(taken & in_words & (wj == 2))
        with m.If(taken):
            m.d.sync += [
                pos.eq(Mux(beat.last, 0, pos + 1)),
                wacc.eq(Cat(wacc[8:], beat.data)),
            ]
            with m.If(beat.last):
                m.d.sync += [
                    wj.eq(0),
                    wk.eq(0),
                    cfg_j.eq(0),
                ]
            with m.Elif(in_words):
                m.d.sync += wj.eq(Mux(wj == 2, 0, wj + 1))
                with m.If(wj == 2):
                    m.d.sync += wk.eq(wk + 1)
            with m.If(is_p):
                with m.Switch(pos):
                    with m.Case(0):
                        m.d.sync += par_bank.eq(beat.data[0])
                    with m.Case(1):
                        m.d.sync += par_addr[:8].eq(beat.data)
                    with m.Case(2):
                        m.d.sync += par_addr[8:].eq(beat.data)

        # Upload check: CRC of every CONFIG / PARAM payload byte in arrival order, and the
        # number of such packets, from reset (16 flip-flops and an XOR network, 16 + a counter).
        upl_crc = Signal(16, init=CRC16_INIT)
        upl_cnt = Signal(16)
        with m.If(taken & (is_c | is_p)):
            m.d.sync += upl_crc.eq(crc16_next(upl_crc, beat.data))
            with m.If(beat.last):
                m.d.sync += upl_cnt.eq(upl_cnt + 1)

        # Words: to a register file (through the pending write) or a D shadow.
        with m.If(wdone):
            with m.If(is_b & (wk < len(COMM_B_WORDS))):
                m.d.sync += [
                    pw_valid.eq(1),
                    pw_bank.eq(Bank.VDC),
                    pw_addr.eq(b_addr[wk]),
                    pw_data.eq(word),
                ]
            with m.If(is_d):
                with m.Switch(wk):
                    with m.Case(0):
                        m.d.sync += d_shadow[0].eq(word)
                    with m.Case(1, 2, 3):
                        m.d.sync += [
                            pw_valid.eq(1),
                            pw_bank.eq(Bank.VDC),
                            pw_addr.eq(g_addr[(wk - 1)[:2]]),
                            pw_data.eq(word),
                        ]
                    with m.Case(4):
                        m.d.sync += d_shadow[1].eq(word)
                    with m.Case(5):
                        m.d.sync += d_shadow[2].eq(word)
                    with m.Case(6):
                        m.d.sync += d_shadow[3].eq(word)
            with m.If(is_p & (wk < 12)):
                m.d.sync += [
                    pw_valid.eq(1),
                    pw_bank.eq(par_bank),
                    pw_addr.eq((par_addr + wk)[:9]),
                    pw_data.eq(word),
                ]

        # CONFIG records: id, then a 32-bit value (the low 24 bits and the sign are used).
        cfg_apply = Signal()
        cfg_value = Signal(32)
        m.d.comb += cfg_value.eq(Cat(cfg_v, beat.data))
        with m.If(taken & is_c):
            with m.If(cfg_j == 0):
                m.d.sync += cfg_id.eq(beat.data)
            with m.Else():
                m.d.sync += cfg_v.eq(Cat(cfg_v[8:], beat.data))
            m.d.sync += cfg_j.eq(Mux((cfg_j == 4) | beat.last, 0, cfg_j + 1))
            m.d.comb += cfg_apply.eq(cfg_j == 4)
        with m.If(cfg_apply):
            with m.Switch(cfg_id):
                with m.Case(Config.MODE):
                    with m.If(cfg_value < len(MODES)):
                        m.d.sync += cfg_mode.eq(cfg_value)
                with m.Case(Config.TICK):
                    with m.If((cfg_value != 0) & (cfg_value < (1 << 16))):
                        m.d.sync += cfg_tick.eq(cfg_value)
                with m.Case(Config.TIMEOUT):
                    m.d.sync += cfg_timeout.eq(cfg_value)
                with m.Case(Config.RAMP):
                    m.d.sync += cfg_ramp.eq(cfg_value)
                with m.Case(Config.TAU_MIN):
                    m.d.sync += cfg_tmin.eq(cfg_value)
                with m.Case(Config.TAU_MAX):
                    m.d.sync += cfg_tmax.eq(cfg_value)
                with m.Case(Config.PERIOD):
                    with m.If((cfg_value >= 2) & (cfg_value < (1 << 24))):
                        m.d.sync += cfg_period.eq(cfg_value)
                with m.Case(Config.SYNC_WINDOW):
                    with m.If(cfg_value < (1 << 24)):
                        m.d.sync += cfg_window.eq(cfg_value)
                with m.Case(Config.COMMIT):
                    with m.If(cfg_value < (1 << 24)):
                        m.d.sync += cfg_commit.eq(cfg_value)
                with m.Case(Config.ARM):
                    with m.If(cfg_value != 0):
                        m.d.sync += arm_pending.eq(1)
                    with m.Else():
                        m.d.comb += disarm.eq(1)
                with m.Case(Config.PRESET):
                    m.d.comb += [
                        enc.preset.eq(1),
                        enc.preset_count.eq(cfg_value),
                    ]
                with m.Case(Config.PRIME):
                    m.d.sync += prime.eq(1)

        # The run starts once the snapshot and the last word are in; its entry was chosen at
        # the end of the Comm B (PRIME pending, or bit 0 of the B flag byte).
        vdc_first = Signal()
        with m.If(vdc_go & ~vdc.busy & ~sw_pending & ~pw_valid):
            m.d.comb += [
                vdc.start.eq(1),
                vdc.entry.eq(Mux(vdc_first, vmc.entries["first"], vmc.entries["main"])),
            ]
            m.d.sync += [
                vdc_go.eq(0),
                vdc_wait.eq(1),
                vdc_fresh.eq(0),
            ]
        with m.If(vdc.mark):
            m.d.sync += [
                vdc_wait.eq(0),
                vdc_fresh.eq(1),
            ]
        # ARM takes effect at the next period boundary (so the state at that boundary does not
        # depend on when the uploads arrived); disarming is immediate (safety first).
        with m.If(disarm):
            m.d.sync += [
                arm_pending.eq(0),
                arming.eq(0),
            ]
        with m.Elif(clr_lo):
            m.d.sync += [
                arm_pending.eq(0),
                arming.eq(1),
            ]
        with m.Elif(clr_hi):
            m.d.sync += arming.eq(0)
        m.d.comb += arm.eq(clr_hi & ~disarm)
        tripped_prev = Signal()
        m.d.sync += tripped_prev.eq(wd.tripped)
        with m.If((wd.tripped & ~tripped_prev) | arm):
            m.d.sync += prime.eq(1)

        # --- control ticks -------------------------------------------------------------------
        # Cycles since the boundary the committed references are for (``ref_t``) and since
        # the boundary of the pending Comm D's arrival period (``pend_t``), saturating.
        ref_t  = Signal(24)
        pend_t = Signal(24)

        def sat_inc(v):
            return Mux(v >= _TIME_MAX, _TIME_MAX, v + 1)

        m.d.sync += [ref_t.eq(sat_inc(ref_t)), pend_t.eq(sat_inc(pend_t))]
        tick_cnt = Signal(16)
        tick     = Signal()
        overruns = Signal(16)
        m.d.comb += tick.eq(boundary | (tick_cnt == 0))
        m.d.sync += tick_cnt.eq(Mux(tick, cfg_tick - 1, tick_cnt - 1))
        j_in = {n: Signal(signed(WORD), name=f"jin_{n}") for n in JOINT_INPUTS}
        tn = Signal(25)
        m.d.comb += [
            tn.eq(ref_t + cfg_tick),
            enc.sample.eq(tick),
            wd.tick.eq(tick),
        ]
        for n in JOINT_INPUTS:
            m.d.comb += joint.inputs[jmc.addr(n) - IO_BASE].eq(j_in[n])
        entries = Array(C(jmc.entries[mode], range(len(jmc.instrs))) for mode in MODES)
        with m.If(tick):
            with m.If(joint.busy):
                with m.If(overruns != 0xFFFF):
                    m.d.sync += overruns.eq(overruns + 1)
            with m.Else():
                count24 = Signal(signed(WORD))
                m.d.comb += count24.eq(Mux(enc.count > (1 << 23) - 1, (1 << 23) - 1,
                                           Mux(enc.count < -(1 << 23), -(1 << 23), enc.count)))
                m.d.sync += [
                    j_in["q"].eq(count24),
                    j_in["qd"].eq(enc.velocity),
                    j_in["tn"].eq(Mux(tn > _TIME_MAX, _TIME_MAX, tn)),
                    j_in["tauD"].eq(d_words[0]),
                    j_in["qd0"].eq(d_words[1]),
                    j_in["vd0"].eq(d_words[2]),
                    j_in["ad0"].eq(d_words[3]),
                ]
                m.d.comb += [
                    joint.start.eq(1),
                    joint.entry.eq(entries[cfg_mode]),
                ]
        m.d.comb += [
            wd.cmd_valid.eq(joint.done),
            wd.cmd.eq(joint.outputs[jmc.addr("tau") - IO_BASE]),
        ]

        # --- status and replies --------------------------------------------------------------
        status = Signal(16)
        m.d.comb += [
            status.eq(Cat(wd.armed, wd.tripped, wd.safe, vdc_fresh, prime, cfg_mode)),
            self.status.eq(status),
        ]
        r_type   = Signal(8)
        r_seq    = Signal(8)
        r_idx    = Signal(range(PAYLOAD))
        c_status = Signal(16)            # Comm C: captured with the request
        c_period = Signal(8)
        a_status = Signal(16)            # Comm A: captured at the period boundary
        a_torque = Signal(signed(WORD))
        a_errors = Signal(16)
        a_overr  = Signal(16)
        a_sync   = Signal(16)
        a_late   = Signal(16)
        a_period = Signal(8)             # (the time-code: captured with the request)
        a_ucrc   = Signal(16)            # (upload CRC and count: captured with the request)
        a_ucnt   = Signal(16)
        a_uperr  = Signal(16)            # (link health: captured with the request)
        a_dnerr  = Signal(16)
        a_rxdrop = Signal(16)
        a_rtdrop = Signal(16)
        with m.If(boundary):
            m.d.sync += [
                a_status.eq(status),
                a_torque.eq(wd.torque),
                a_errors.eq(enc.errors),
                a_overr.eq(overruns),
                a_sync.eq(Mux(resync & wd.armed & (sync_errors != 0xFFFF), sync_errors + 1,
                              sync_errors)),   # a resync reports itself
                a_late.eq(late_d),
            ]
        forces   = Cat(*(vdc.outputs[vmc.addr(f"F{L}{k}") - IO_BASE]
                         for L in "AB" for k in range(6)))
        payload_a = Cat(snap_count, snap_qd, a_torque, a_status, a_errors, a_period, a_overr,
                        a_sync, a_late, a_ucrc, a_ucnt, a_uperr, a_dnerr, a_rxdrop, a_rtdrop,
                        C(0, 8 * PAYLOAD - 264))
        payload_c = Cat(forces, c_status, c_period, C(0, 8))
        # The reply is loaded into a shift register and sent from its low byte: cheaper on a
        # Virtex-II than a 40-way byte multiplexer (320 flip-flops instead of ~700 LUTs).
        r_shift = Signal(8 * PAYLOAD)
        tx_a_ev  = Signal()              # observation port: the reply FSM leaves Idle
        tx_c_ev  = Signal()
        m.d.comb += [
            self.tx.p.header.dest.eq(0),
            self.tx.p.header.type.eq(r_type),
            self.tx.p.header.seq.eq(r_seq),
            self.tx.p.data.eq(r_shift[:8]),
            self.tx.p.last.eq(r_idx == PAYLOAD - 1),
        ]
        with m.FSM(name="reply"):
            with m.State("Idle"):
                m.d.comb += [
                    tx_a_ev.eq(reply_a),
                    tx_c_ev.eq(~reply_a & reply_c & ~vdc_go & ~vdc_wait),
                ]
                with m.If(reply_a):
                    m.d.sync += [
                        r_idx.eq(0),
                        r_shift.eq(payload_a),
                        r_type.eq(PacketType.COMM_A),
                        r_seq.eq(seq_a),
                        reply_a.eq(0),
                    ]
                    m.next = "Send"
                with m.Elif(reply_c & ~vdc_go & ~vdc_wait):
                    m.d.sync += [
                        r_idx.eq(0),
                        r_shift.eq(payload_c),
                        r_type.eq(PacketType.COMM_C),
                        r_seq.eq(seq_c),
                        reply_c.eq(0),
                    ]
                    m.next = "Send"
            with m.State("Send"):
                m.d.comb += self.tx.valid.eq(1)
                with m.If(self.tx.ready):
                    m.d.sync += [
                        r_idx.eq(r_idx + 1),
                        r_shift.eq(r_shift >> 8),
                    ]
                    with m.If(r_idx == PAYLOAD - 1):
                        m.next = "Idle"

        # End of packet (after the reply FSM, so a request arriving as the previous one is taken
        # is not lost): start the VDC, commit Comm D, queue replies.
        full      = pos == PAYLOAD - 1
        with m.If(taken & beat.last):
            m.d.comb += packet_event.eq(1)
            with m.If(is_b & full):
                m.d.sync += [
                    vdc_go.eq(1),
                    vdc_first.eq(prime | beat.data[0]),
                    prime.eq(0),
                ]
            with m.If(is_d & full):
                with m.If(wd.armed):
                    m.d.sync += [dn.eq(ds) for dn, ds in zip(d_next, d_shadow, strict=True)]
                    m.d.sync += pend_t.eq(sat_inc(tt))
                    m.d.comb += d_arrive.eq(1)
                with m.Else():
                    m.d.sync += [dw.eq(ds) for dw, ds in zip(d_words, d_shadow, strict=True)]
                    m.d.sync += ref_t.eq(sat_inc(tt))
            with m.If(ptype == PacketType.COMM_A):
                m.d.sync += [
                    reply_a.eq(1),
                    seq_a.eq(beat.header.seq),
                    a_period.eq(self.period),
                    a_ucrc.eq(upl_crc),
                    a_ucnt.eq(upl_cnt),
                    a_uperr.eq(saturating_sum(self.up_errors[f] for f in ERROR_CLASSES)),
                    a_dnerr.eq(saturating_sum(self.down_errors[f] for f in ERROR_CLASSES)),
                    a_rxdrop.eq(saturating_sum(self.rx_stats[f] for f in RX_DROPS)),
                    a_rtdrop.eq(self.dropped),
                ]
            with m.If(ptype == PacketType.COMM_C):
                # FRESH: the forces the reply will carry (it waits for a running VDC) come
                # from this period's Comm B.
                m.d.sync += [
                    reply_c.eq(1),
                    seq_c.eq(beat.header.seq),
                    c_status.eq(status | ((vdc_go | vdc_wait) << 3)),
                    c_period.eq(self.period),
                ]
        m.d.comb += wd.packet.eq(packet_event)

        # Comm D while armed: committed at phase COMMIT of the period (all joints on the same
        # grid); one that arrives at or after COMMIT waits for the next commit point, counted.
        # Its references are for the start of the period it arrived in: the ticks count their
        # time from that boundary (``ref_t``), across the next boundary until the next commit,
        # so a commit point later than the boundary never sends the reference back a period.
        with m.If(phase == cfg_commit):
            with m.If(d_pending):
                m.d.sync += [dw.eq(dn) for dw, dn in zip(d_words, d_next, strict=True)]
                m.d.sync += ref_t.eq(sat_inc(pend_t))
            m.d.sync += d_pending.eq(d_arrive)
        with m.Elif(d_arrive):
            m.d.sync += d_pending.eq(1)
        with m.If(d_arrive & (phase >= cfg_commit) & (late_d != 0xFFFF)):
            m.d.sync += late_d.eq(late_d + 1)

        # --- observation port (NodeEvent strobes; test points, nothing reads them) -------------
        ends = taken & beat.last
        strobes = {
            Ev.BOUNDARY:  boundary,
            Ev.RESYNC:    resync,
            Ev.TIMECODE:  self.period_start,
            Ev.RX_A:      ends & (ptype == PacketType.COMM_A),
            Ev.RX_B:      ends & is_b & full,
            Ev.RX_C:      ends & (ptype == PacketType.COMM_C),
            Ev.RX_D:      ends & is_d & full,
            Ev.VDC_START: vdc.start,
            Ev.VDC_DONE:  vdc.mark,
            Ev.VDC_END:   vdc.done,
            Ev.TX_A:      tx_a_ev,
            Ev.TX_C:      tx_c_ev,
            Ev.COMMIT:    ((phase == cfg_commit) & d_pending) | (ends & is_d & full & ~wd.armed),
        }
        for ev, strobe in strobes.items():
            m.d.comb += self.events[ev.bit_length() - 1].eq(strobe)
        return m
