"""Transaction-level reference of the node core (:class:`~hdl.node.core.NodeCore`).

It composes the block references: :class:`~hdl.node.vdc_ref.VdcModel`,
:class:`~hdl.node.joint_ref.JointModel`, :mod:`~hdl.node.trig_ref` and the watchdog rules of
:mod:`~hdl.node.watchdog_ref`, driven by events with their clock cycle. The encoder is not in
it: callers give the count and velocity the encoder interface (or its reference,
:class:`~hdl.node.encoder_ref.EncoderModel`) shows at each event. It is fast enough to stand
in for the gateware in long runs (the ``model`` backend).

Event timing, as in the gateware:

* :meth:`period_start` at the time-code strobe's cycle;
* :meth:`packet` at the cycle its last byte is taken; Comm D values reach the joint engine from
  the next cycle on; the watchdog's silence restarts there;
* :meth:`tick` at each control tick's cycle; its command lands ``cycles(mode)`` cycles later
  (:meth:`~hdl.node.isa.Microcode.cycles`), then the limits and the watchdog apply.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hdl.link.packet_ref import PacketType

from .encoder_ref import EncoderParams
from .fixed import saturate
from .joint import joint_microcode
from .joint_ref import MODES as JOINT_MODES
from .joint_ref import JointInputs, JointModel, JointParams
from .regs import (COMM_B_WORDS, COMM_D_WORDS, CONFIG_DEFAULTS, PAYLOAD, Bank, Config, Status,
                   pack_words, unpack_words)
from .trig_ref import sin_cos
from .vdc import vdc_microcode
from .vdc_ref import VdcInputs, VdcModel, VdcParams

__all__ = ["NodeModel"]

_TIME_MAX = (1 << 23) - 1


def _zero_vdc() -> VdcModel:
    z13, z6 = [[0] * 13, [0] * 13], [[0] * 6, [0] * 6]
    return VdcModel(VdcParams(K=z6, rho_T=[r[:] for r in z13], lower=[r[:] for r in z13],
                              upper=[r[:] for r in z13], inv_T=0), [r[:] for r in z13])


@dataclass
class NodeModel:
    """State of one node core at transaction level (see the module docstring).

    Attributes
    ----------
    vdc : VdcModel
    joint : JointModel
    config : dict of Config to int
    d_words : list of 4 int
        Committed Comm D words ``τ_D, q_d0, q̇_d0, q̈_d0``.
    g_words : list of 3 int
    forces : list of 12 int
        FORCE words of the last VDC run (Link a, then Link b): what Comm C returns.
    """

    encoder: EncoderParams = field(default_factory=EncoderParams)
    vdc: VdcModel = field(default_factory=_zero_vdc)
    joint: JointModel = field(default_factory=lambda: JointModel(JointParams(*([0] * 17))))
    config: dict = field(default_factory=lambda: dict(CONFIG_DEFAULTS))
    d_words: list = field(default_factory=lambda: [0, 0, 0, 0])
    g_words: list = field(default_factory=lambda: [0, 0, 0])
    b_words: list = field(default_factory=lambda: [0] * 13)
    snap_count: int = 0
    snap_qd: int = 0
    cos_q: int = 0
    sin_q: int = 0
    period_cycle: int = 0
    prime: bool = True
    fresh: bool = False
    armed: bool = False
    tripped: bool = False
    torque: int = 0
    last_packet: int = 0
    overruns: int = 0
    forces: list = field(default_factory=lambda: [0] * 12)
    _busy_until: int = -1
    _landing: tuple | None = None

    # --- events -------------------------------------------------------------------------------
    def period_start(self, now: int, count: int, qd: int) -> None:
        """Time-code strobe at cycle ``now``; ``count``, ``qd`` the encoder outputs then."""
        self._watch(now)
        self.snap_count, self.snap_qd = count, qd
        self.cos_q, self.sin_q = sin_cos(count, self.encoder.counts_per_rev)
        self.period_cycle = now
        self.fresh = False

    def packet(self, now: int, ptype: int, payload: bytes, period: int = 0,
               enc_errors: int = 0):
        """A packet whose last byte is taken at cycle ``now`` (``period``: the time-code value
        then; ``enc_errors``: the encoder's illegal-transition count then).

        Returns
        -------
        bytes or None
            The reply payload for Comm A and Comm C requests (Comm C: once the VDC ran).
        """
        self._watch(now)
        payload = bytes(payload)
        reply = None
        if ptype == PacketType.COMM_B and len(payload) == PAYLOAD:
            self.b_words = unpack_words(payload, len(COMM_B_WORDS))
            if self.prime or payload[-1] & 1:
                self.vdc.primed = False
            self.prime = False
            w = self.b_words
            x = VdcInputs(w[0], w[1:7], w[7:13], self.snap_qd, self.cos_q, self.sin_q,
                          list(self.g_words))
            F_a, F_b = self.vdc.step(x)
            self.forces = F_a + F_b
            self.fresh = True
        elif ptype == PacketType.COMM_D:
            # g_C goes to the VDC word by word as it arrives; the rest commits on a full packet.
            w = unpack_words(payload, min(len(payload) // 3, len(COMM_D_WORDS)))
            for k in range(1, min(4, len(w))):
                self.g_words[k - 1] = w[k]
            if len(payload) == PAYLOAD:
                self.d_words = [w[0], w[4], w[5], w[6]]
        elif ptype == PacketType.COMM_A:
            reply = self._reply_a(period, enc_errors)
        elif ptype == PacketType.COMM_C:
            reply = self._reply_c(period)
        elif ptype == PacketType.CONFIG:
            for k in range(0, len(payload) - 4, 5):
                self._config(now, payload[k], int.from_bytes(payload[k + 1:k + 5], "little"))
        elif ptype == PacketType.PARAM and len(payload) >= 3:
            bank, addr = payload[0] & 1, int.from_bytes(payload[1:3], "little")
            for j, w in enumerate(unpack_words(payload, min(12, (len(payload) - 3) // 3), 3)):
                self._param(bank, (addr + j) & 0x1FF, w)
        self.last_packet = now
        return reply

    def tick(self, now: int, count: int, qd: int) -> int:
        """Control tick at cycle ``now``; returns the torque word after its command landed."""
        self._watch(now)
        if self.armed and self.tripped:
            ramp = self.config[Config.RAMP]
            self.torque = 0 if abs(self.torque) <= ramp else \
                self.torque - ramp if self.torque > 0 else self.torque + ramp
        if now < self._busy_until:
            self.overruns = min(self.overruns + 1, 0xFFFF)
            return self.torque
        mode = JOINT_MODES[self.config[Config.MODE]]
        tick = self.config[Config.TICK]
        tt = min(now - self.period_cycle, _TIME_MAX)
        x = JointInputs(q=saturate(count), qd=qd, tn=min(tt + tick, _TIME_MAX),
                        tau_D=self.d_words[0], qd0=self.d_words[1], vd0=self.d_words[2],
                        ad0=self.d_words[3])
        tau, _, _ = self.joint.tick(mode, x)
        cycles = joint_microcode().cycles(mode)
        self._busy_until = now + cycles + 1
        done = now + cycles
        self._watch(done)
        if not self.armed:
            landed = 0
        elif not self.tripped:
            landed = min(max(tau, self.config[Config.TAU_MIN]), self.config[Config.TAU_MAX])
        else:
            landed = self.torque
        self._landing = (done + 1, landed)      # visible from the cycle after the command
        return landed

    # --- helpers ------------------------------------------------------------------------------
    def _watch(self, now: int) -> None:
        """Land a pending command; the watchdog trips when the silence reaches the timeout
        (visible one cycle later)."""
        if self._landing is not None and now >= self._landing[0]:
            self.torque = self._landing[1]
            self._landing = None
        if self.armed and not self.tripped and now >= self.last_packet + 1 + \
                self.config[Config.TIMEOUT]:
            self.tripped = True
            self.prime = True

    @property
    def status(self) -> Status:
        s = Status(0)
        if self.armed:
            s |= Status.ARMED
        if self.tripped:
            s |= Status.TRIPPED
            if self.torque == 0:
                s |= Status.SAFE
        if self.fresh:
            s |= Status.FRESH
        if self.prime:
            s |= Status.PRIME
        return Status(int(s) | (self.config[Config.MODE] << 5))

    def _reply_a(self, period: int, enc_errors: int) -> bytes:
        out = (self.snap_count & 0xFFFFFFFF).to_bytes(4, "little")
        out += pack_words([self.snap_qd, self.torque])
        out += int(self.status).to_bytes(2, "little") + enc_errors.to_bytes(2, "little")
        out += bytes([period])
        out += self.overruns.to_bytes(2, "little")
        return out + bytes(PAYLOAD - len(out))

    def _reply_c(self, period: int) -> bytes:
        out = pack_words(self.forces)
        out += int(self.status).to_bytes(2, "little") + bytes([period])
        return out + bytes(PAYLOAD - len(out))

    def _config(self, now: int, reg: int, value: int) -> None:
        signed = value - (1 << 32) if value >> 31 else value
        if reg == Config.MODE and value < len(JOINT_MODES):
            self.config[Config.MODE] = value
        elif reg == Config.TICK and 0 < value < (1 << 16):
            self.config[Config.TICK] = value
        elif reg == Config.TIMEOUT:
            self.config[Config.TIMEOUT] = value
        elif reg == Config.RAMP:
            self.config[Config.RAMP] = value & 0xFFFFFF
        elif reg in (Config.TAU_MIN, Config.TAU_MAX):
            self.config[Config(reg)] = saturate(((signed + (1 << 23)) % (1 << 24)) - (1 << 23))
        elif reg == Config.ARM:
            if value:
                self.armed, self.tripped, self.prime = True, False, True
            else:
                self.armed = False
                self.torque = 0
                self._landing = None
        elif reg == Config.PRIME:
            self.prime = True

    def _param(self, bank: int, addr: int, w: int) -> None:
        if bank == Bank.JOINT:
            mc = joint_microcode()
            names = {mc.addr(n): n for n in self.joint.params.words()}
            if addr in names:
                setattr(self.joint.params, names[addr], w)
            states = {mc.addr("qdes"): "q_des", mc.addr("vdes"): "v_des",
                      mc.addr("ilo_s"): "i_lo", mc.addr("ihi_s"): "i_hi"}
            if addr in states:
                setattr(self.joint, states[addr], w)
            return
        mc = vdc_microcode()
        name = next((r.name for r in mc.regs.values() if r.addr == addr and r.kind in
                     ("param", "state", "host")), None)
        if name is None:
            return
        p, links = self.vdc.params, {"A": 0, "B": 1}
        if name == "invT":
            p.inv_T = w
        elif name[0] == "K" and name[1] in links:
            p.K[links[name[1]]][int(name[2:])] = w
        elif name.startswith("th"):
            self.vdc.theta[links[name[2]]][int(name[3:])] = w
        elif name.startswith(("lo", "hi")):
            arr = p.lower if name.startswith("lo") else p.upper
            arr[links[name[2]]][int(name[3:])] = w
        elif name[0] == "r" and name[1] in links:
            p.rho_T[links[name[1]]][int(name[2:])] = w
        elif name.startswith("pC"):
            self.vdc.prev_C[int(name[2:])] = w
        elif name == "pqdr":
            self.vdc.prev_qd_r = w
        elif name.startswith("gC"):
            self.g_words[int(name[2:])] = w
