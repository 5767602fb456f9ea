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

Structure: the engines and the encoder (:class:`~hdl.node.encoder.QuadratureEncoder`,
:class:`~hdl.node.trig.SinCos`, :class:`~hdl.node.vdc.VdcUnit`,
:class:`~hdl.node.joint.JointUnit`, :class:`~hdl.node.watchdog.Watchdog`) and seven
sub-components with their own signatures, which this module only wires together
(docs/node.md "Structure"):

* :class:`~hdl.node.decoder.PacketDecoder` — packets in; register-file words, CONFIG records,
  Comm D words, packet ends and the upload check out;
* :class:`~hdl.node.config.NodeConfig` — the CONFIG registers, and when ARM takes effect;
* :class:`~hdl.node.timer.PeriodTimer` — phase, boundary, time-code monitor, the snapshot;
* :class:`~hdl.node.commit.ReferenceCommit` — Comm D's references and their commit point;
* :class:`~hdl.node.ticks.ControlTicks` — the control ticks and the joint engine's inputs;
* :class:`~hdl.node.vdc_seq.VdcSequencer` — the VDC engine's host port and runs, FRESH, PRIME;
* :class:`~hdl.node.reply.ReplyBuilder` — Comm A / Comm C replies onto the byte stream.

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
* Safe stop (IEC 61800-5-2 SS1 at monitored standstill, SS1-t as the time limit;
  docs/node.md "Safe stop"): after a watchdog trip the ticks run the PID entry on node-local
  references (their target the tick's count while the joint stops, frozen at the first hold
  tick with the joint at rest: velocity within ±STANDSTILL, the brake on, or the rule off);
  the ``brake`` output once the ticks' velocity word has been within ±STANDSTILL for
  STANDSTILL_TICKS consecutive ticks, at the latest STOP_CYCLES after the trip; the hold goes
  on for BRAKE_CYCLES from the brake, then the torque ramps to zero (STO); status bits HOLD,
  BRAKE and STOP_LIMIT.
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
from mrm_cosim.hdl.link.packet import Beat, PacketType, RxStats
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.isa import IO_BASE
from mrm_cosim.protocol.joint_program import INPUTS as JOINT_INPUTS
from mrm_cosim.protocol.joint_program import pid_formats
from mrm_cosim.protocol.link import ERROR_CLASSES
from mrm_cosim.protocol.regs import RX_DROPS, Bank
from mrm_cosim.protocol.regs import NodeEvent as Ev

from .commit import ReferenceCommit
from .config import NodeConfig
from .decoder import CommDWords, PacketDecoder
from .dmp import DmpGenerator
from .dmp_seq import DmpTiming
from .encoder import QuadratureEncoder
from .joint import JointUnit
from .reply import ReplyBuilder
from .ticks import ControlTicks
from .timer import PeriodTimer
from .trig import SinCos
from .vdc import VdcUnit
from .vdc_seq import VdcSequencer
from .watchdog import Watchdog

__all__ = ["NodeCore"]


class NodeCore(wiring.Component):
    """One module's compute core (see the module docstring).

    Parameters
    ----------
    encoder : EncoderParams
        Encoder interface parameters (resolution, clock, filter, windows).
    pid_shift : int
        PID gain shift of the joint program
        (:func:`~mrm_cosim.protocol.joint_program.pid_formats`).

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
    brake : Out(1)
        Engage the joint's holding brake (the watchdog's safe stop, docs/node.md "Safe stop").
    status : Out(16)
        :class:`~protocol.regs.Status` bits.
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
        Observation port: one-cycle :class:`~protocol.regs.NodeEvent` strobes (boundary,
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
    brake:        Out(1)
    status:       Out(16)
    count:        Out(signed(32))
    velocity:     Out(signed(WORD))
    up_errors:    In(ErrorCounts)
    down_errors:  In(ErrorCounts)
    rx_stats:     In(RxStats)
    dropped:      In(16)
    events:       Out(16)

    def __init__(self, *, encoder: EncoderParams | None = None, pid_shift: int = 0):
        self._enc = encoder or EncoderParams()
        pid_formats(pid_shift)                  # validates
        self._pid_shift = pid_shift
        super().__init__()

    @property
    def encoder_params(self) -> EncoderParams:
        return self._enc

    def elaborate(self, platform):
        m = Module()
        m.submodules.encoder  = enc   = QuadratureEncoder(self._enc)
        m.submodules.trig     = trig  = SinCos(counts_per_rev=self._enc.counts_per_rev)
        m.submodules.vdc      = vdc   = VdcUnit()
        m.submodules.joint    = joint = JointUnit(self._pid_shift)
        m.submodules.watchdog = wd    = Watchdog()
        vmc, jmc = vdc.microcode, joint.microcode
        m.submodules.decoder  = dec   = PacketDecoder(vmc)
        m.submodules.config   = cfg   = NodeConfig()
        m.submodules.timer    = timer = PeriodTimer()
        m.submodules.refs     = refs  = ReferenceCommit()
        m.submodules.ticks    = ticks = ControlTicks(jmc)
        m.submodules.vdc_seq  = vseq  = VdcSequencer(vmc)
        m.submodules.reply    = reply = ReplyBuilder()

        # --- packets in: decoded into words, CONFIG records and packet ends -------------------
        wiring.connect(m, rx=wiring.flipped(self.rx), decoder=dec.rx)
        # (NodeConfig holds the record a cycle: CONFIG acts the cycle after its last byte)
        wiring.connect(m, decoder=dec.config, config=cfg.config)
        for sink in (refs.ends, vseq.ends, reply.requests):
            m.d.comb += [sink.valid.eq(dec.ends.valid), sink.p.eq(dec.ends.p)]
        # A pending word goes to the engine of its bank (the generator takes one any cycle;
        # a word for no bank is dropped).
        for_vdc = dec.words.p.bank == Bank.VDC
        for_joint = dec.words.p.bank == Bank.JOINT
        m.d.comb += [
            vseq.words.valid.eq(dec.words.valid & for_vdc),
            vseq.words.p.eq(dec.words.p),
            ticks.words.valid.eq(dec.words.valid & for_joint),
            ticks.words.p.eq(dec.words.p),
            dec.words.ready.eq(Mux(for_vdc, vseq.words.ready,
                                   Mux(for_joint, ticks.words.ready, 1))),
            vseq.hold.eq(dec.words.valid),
        ]
        jrefs, jref_time, dmp_select, dmp_overruns, dmp_step = self._dmp(m, dec, cfg, timer, refs)
        self._timer(m, cfg, timer, ticks, wd)

        # --- encoder, period timer and its snapshot, CORDIC -----------------------------------
        status = Signal(16)
        m.d.comb += [
            enc.a.eq(self.enc_a),
            enc.b.eq(self.enc_b),
            enc.sample.eq(ticks.tick),
            enc.preset.eq(cfg.preset),
            enc.preset_count.eq(cfg.preset_count),
            self.count.eq(enc.count),
            self.velocity.eq(enc.velocity),
            timer.live.count.eq(enc.count),
            timer.live.velocity.eq(enc.velocity),
            timer.live.torque.eq(wd.torque),
            timer.live.status.eq(status),
            timer.live.errors.eq(enc.errors),
            timer.live.overruns.eq(ticks.overruns),
            timer.live.late_d.eq(refs.late_d),
            trig.start.eq(timer.boundary),
            trig.count.eq(enc.count),
            cfg.pre_boundary.eq(timer.pre_boundary),
            cfg.boundary.eq(timer.boundary),
            cfg.joint_busy.eq(joint.busy),
        ]

        # --- VDC engine: snapshot and words in, runs after Comm B -------------------------------
        m.d.comb += [
            vseq.boundary.eq(timer.boundary),
            vseq.velocity.eq(timer.snapshot.velocity),
            vseq.trig_done.eq(trig.done),
            vseq.cos.eq(trig.cos),
            vseq.sin.eq(trig.sin),
            vseq.prime.eq(cfg.prime),
            vseq.arm.eq(cfg.arm),
            vseq.tripped.eq(wd.tripped),
            vseq.busy.eq(vdc.busy),
            vseq.mark.eq(vdc.mark),
            vdc.start.eq(vseq.start),
            vdc.entry.eq(vseq.entry),
            vdc.host_addr.eq(vseq.host_addr),
            vdc.host_wdata.eq(vseq.host_wdata),
            vdc.host_we.eq(vseq.host_we),
        ]

        # --- joint engine: Comm D references, control ticks; torque through the watchdog -----
        m.d.comb += [
            refs.comm_d.eq(dec.comm_d),
            refs.armed.eq(wd.armed),
            refs.phase.eq(timer.phase),
            refs.elapsed.eq(timer.elapsed),
            refs.commit.eq(cfg.commit),
            ticks.boundary.eq(timer.boundary),
            ticks.cycles.eq(cfg.tick),
            ticks.mode.eq(cfg.mode),
            ticks.count.eq(enc.count),
            ticks.velocity.eq(enc.velocity),
            ticks.refs.eq(jrefs),
            ticks.ref_time.eq(jref_time),
            ticks.busy.eq(joint.busy),
            ticks.clear_lo.eq(cfg.clear_lo),
            ticks.clear_hi.eq(cfg.clear_hi),
            ticks.hold.eq(wd.holding),
            ticks.rest.eq(wd.rest),
            ticks.trail.eq(cfg.stop_trail),
            joint.start.eq(ticks.start),
            joint.entry.eq(ticks.entry),
            joint.host_addr.eq(ticks.host_addr),
            joint.host_wdata.eq(ticks.host_wdata),
            joint.host_we.eq(ticks.host_we),
            wd.timeout.eq(cfg.timeout),
            wd.ramp.eq(cfg.ramp),
            wd.tau_min.eq(cfg.tau_min),
            wd.tau_max.eq(cfg.tau_max),
            wd.stop_cycles.eq(cfg.stop_cycles),
            wd.brake_cycles.eq(cfg.brake_cycles),
            wd.standstill.eq(cfg.standstill),
            wd.standstill_ticks.eq(cfg.standstill_ticks),
            wd.velocity.eq(enc.velocity),
            wd.arm.eq(cfg.arm),
            wd.disarm.eq(cfg.disarm),
            wd.packet.eq(dec.ends.valid),
            wd.tick.eq(ticks.tick),
            wd.cmd_valid.eq(joint.done),
            wd.cmd.eq(joint.outputs[jmc.addr("tau") - IO_BASE]),
            self.torque.eq(wd.torque),
            self.brake.eq(wd.brake),
        ]
        for n in JOINT_INPUTS:
            m.d.comb += joint.inputs[jmc.addr(n) - IO_BASE].eq(ticks.inputs[n])

        # --- status and replies ---------------------------------------------------------------
        m.d.comb += [
            status.eq(Cat(wd.armed, wd.tripped, wd.safe, vseq.fresh, vseq.primed, cfg.mode,
                          dmp_select, wd.holding, wd.brake, wd.limit)),
            self.status.eq(status),
            reply.snapshot.eq(timer.snapshot),
            reply.sync_errors.eq(timer.sync_errors),
            reply.period.eq(self.period),
            reply.upload_crc.eq(dec.upload_crc),
            reply.upload_count.eq(dec.upload_count),
            reply.dmp_overruns.eq(dmp_overruns),
            reply.status.eq(status),
            reply.vdc_pending.eq(vseq.pending),
        ]
        self._link_health(m, reply)
        forces = [vdc.outputs[vmc.addr(f"F{L}{k}") - IO_BASE] for L in "AB" for k in range(6)]
        m.d.comb += [reply.forces[i].eq(f) for i, f in enumerate(forces)]
        wiring.connect(m, reply=reply.tx, tx=wiring.flipped(self.tx))

        self._events(m, dec.ends, timer, vdc, reply, refs, dmp_step)
        return m

    def _timer(self, m, cfg, timer, ticks, wd):
        """The period timer's settings and time-code; its tail gates the control ticks."""
        m.d.comb += [
            timer.period.eq(cfg.period),
            timer.window.eq(cfg.window),
            timer.time_code.eq(self.period_start),
            timer.armed.eq(wd.armed),
            timer.discipline.eq(cfg.discipline),
            timer.restart.eq(cfg.discipline_set),
            timer.tick.eq(cfg.tick),
            timer.window_next.eq(cfg.window_next),
            timer.pm1_next.eq(cfg.pm1_next),
            timer.pmw_next.eq(cfg.pmw_next),
            timer.pmt_next.eq(cfg.pmt_next),
            ticks.tail.eq(timer.tail),
        ]

    def _link_health(self, m, reply):
        """Comm A's link health: the two codecs' error classes and the drops, each summed
        saturating."""
        m.d.comb += [
            reply.link.up_link_errors.eq(
                saturating_sum(self.up_errors[f] for f in ERROR_CLASSES)),
            reply.link.down_link_errors.eq(
                saturating_sum(self.down_errors[f] for f in ERROR_CLASSES)),
            reply.link.rx_dropped.eq(saturating_sum(self.rx_stats[f] for f in RX_DROPS)),
            reply.link.router_dropped.eq(self.dropped),
        ]

    def _dmp(self, m, dec, cfg, timer, refs):
        """The joint-side motion primitive: the generator (its bank's words, CONFIG DMP's
        strobes, steps on the period grid) and the references the joint takes — the
        generator's while it is selected, with Comm D's ``τ_D`` (docs/dmp.md).

        Returns ``(references, their time, selected, generator overruns, step strobe)``."""
        m.submodules.dmp     = gen  = DmpGenerator()
        m.submodules.dmp_seq = dseq = DmpTiming()
        m.d.comb += [
            gen.host_addr.eq(dec.words.p.addr),
            gen.host_data.eq(dec.words.p.data),
            gen.host_we.eq(dec.words.valid & (dec.words.p.bank == Bank.DMP)),
            dseq.boundary.eq(timer.boundary),
            dseq.tail.eq(cfg.discipline.enable & (timer.phase >= cfg.period)),
            dseq.gen_ready.eq(gen.ready),
            dseq.step_cycles.eq(cfg.dmp_step),
            dseq.off.eq(cfg.dmp_off),
            dseq.start.eq(cfg.dmp_start),
            dseq.stop.eq(cfg.dmp_stop),
            gen.start.eq(dseq.gen_start),
            gen.step.eq(dseq.gen_step),
            gen.stop.eq(dseq.gen_stop),
        ]
        jrefs = Signal(CommDWords)
        jref_time = Signal(24)
        sel = dseq.select
        m.d.comb += [
            jrefs.tau.eq(refs.refs.tau),
            jrefs.qd0.eq(Mux(sel, gen.qd0, refs.refs.qd0)),
            jrefs.vd0.eq(Mux(sel, gen.vd0, refs.refs.vd0)),
            jrefs.ad0.eq(Mux(sel, gen.ad0, refs.refs.ad0)),
            jref_time.eq(Mux(sel, dseq.ref_time, refs.ref_time)),
        ]
        return jrefs, jref_time, sel, gen.overruns, dseq.gen_step

    def _events(self, m, ends, timer, vdc, reply, refs, dmp_step):
        """The observation port: NodeEvent strobes, test points that nothing reads."""
        strobes = {
            Ev.BOUNDARY:  timer.boundary,
            Ev.RESYNC:    timer.resync,
            Ev.TIMECODE:  self.period_start,
            Ev.RX_A:      ends.valid & (ends.p.type == PacketType.COMM_A),
            Ev.RX_B:      ends.valid & (ends.p.type == PacketType.COMM_B) & ends.p.full,
            Ev.RX_C:      ends.valid & (ends.p.type == PacketType.COMM_C),
            Ev.RX_D:      ends.valid & (ends.p.type == PacketType.COMM_D) & ends.p.full,
            Ev.VDC_START: vdc.start,
            Ev.VDC_DONE:  vdc.mark,
            Ev.VDC_END:   vdc.done,
            Ev.TX_A:      reply.sending_a,
            Ev.TX_C:      reply.sending_c,
            Ev.COMMIT:    refs.committed,
            Ev.DMP_STEP:  dmp_step,
        }
        for ev, strobe in strobes.items():
            m.d.comb += self.events[ev.bit_length() - 1].eq(strobe)
