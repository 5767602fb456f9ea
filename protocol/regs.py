"""The node's registers and packet payloads, as the master sees them (docs/node.md "Packets").

All multi-byte fields are little-endian; 24-bit words are signed fixed point (:mod:`.fixed`).
Every Comm payload is the paper's 40 bytes.

======== =====  ==============================================================================
packet   dir    payload
======== =====  ==============================================================================
COMM_A   m→s    request (any payload); the node answers with a COMM_A packet, every field
         s→m    but ``period`` taken at the last period boundary of the node's timer:
                ``count`` int32 (encoder count) · ``q̇`` VEL · ``τ`` FORCE (torque applied
                then) · ``status`` u16 (:class:`Status`) · ``errors`` u16 (illegal encoder
                transitions) · ``period`` u8 (last time-code) · ``overruns`` u16 (control
                ticks skipped) · ``sync_errors`` u16 (time-codes outside the sync window
                while armed) · ``late_d`` u16 (Comm D packets after the commit phase) ·
                ``upload_crc`` u16, ``upload_count`` u16 (CRC-16/CCITT-FALSE of every
                CONFIG and PARAM payload since reset, and their number; both taken with the
                request, see :func:`upload_check`) · link health, taken with the request:
                ``up_link_errors``, ``down_link_errors`` u16 (the upstream and downstream
                codecs' error counters, five classes summed) · ``rx_dropped`` u16 (frames
                the depacketizer dropped: CRC, length, EEP) · ``router_dropped`` u16
                (packets the router discarded) · ``dmp_overruns`` u16 (steps of the
                primitive generator that found their references not ready; taken with the
                request) · zeros
COMM_B   m→s    ``q̇_r`` · ``V_C[6]`` · ``V_rC[6]`` (13 VEL words, 39 bytes) · flags u8 (bit 0:
                restart the derivative history)
COMM_C   m→s    request; the node answers once its VDC run for the last Comm B has its forces:
         s→m    ``F_a[6]`` · ``F_b[6]`` (FORCE, 36 bytes) · ``status`` u16 · ``period`` u8 · 0
COMM_D   m→s    ``τ_D`` FORCE (τ_Lr in VDC mode, feedforward in PID mode, the torque in
                torque mode) · ``g_C[3]`` ACC (upward gravity in {C}, used by the next VDC
                run) · ``q_d0`` POS · ``q̇_d0`` VEL · ``q̈_d0`` ACC (references at the period
                start) · zeros
CONFIG   m→s    up to 8 records ``id`` u8 · ``value`` int32 (:class:`Config`)
PARAM    m→s    ``bank`` u8 (0 VDC, 1 joint, 2 primitive generator) · ``address`` u16 · up to
                12 words (24-bit)
======== =====  ==============================================================================
"""

from __future__ import annotations

import enum
import math
import struct

import numpy as np

from mrm_cosim.errors import InputError

from .crc import CRC16_INIT, crc16
from .fixed import (ACC, FORCE, GAIN, POS, RHOT, THETA, VEL, WORD_MAX, WORD_MIN, saturate,
                    theta_group)
from .joint_program import MODES as JOINT_MODES
from .joint_program import JointParams, joint_microcode
from .packet import DATA_PAYLOAD
from .vdc_program import LINKS, VdcParams, theta_words, vdc_microcode, vdc_param_words

__all__ = ["PAYLOAD", "COMM_B_WORDS", "COMM_D_WORDS", "Config", "Bank", "Status", "MODES",
           "pack_words", "unpack_words", "pack_comm_b", "pack_comm_d", "parse_comm_a",
           "parse_comm_c", "config_payloads", "param_payloads", "vdc_upload", "joint_upload",
           "CONFIG_DEFAULTS", "DmpControl", "upload_check", "RX_DROPS", "LINK_HEALTH", "NodeEvent"]

PAYLOAD = DATA_PAYLOAD
#: The depacketizer's counters of frames it dropped (:class:`~mrm_cosim.hdl.link.packet.RxStats`),
#: summed into Comm A's ``rx_dropped``.
RX_DROPS = ("crc", "length", "eep")
#: Comm A's link-health fields (bytes 25–32), each u16, saturating.
LINK_HEALTH = ("up_link_errors", "down_link_errors", "rx_dropped", "router_dropped")
COMM_B_WORDS = ("qdr",) + tuple(f"VC{k}" for k in range(6)) + tuple(f"VrC{k}" for k in range(6))
COMM_D_WORDS = ("tauD", "gC0", "gC1", "gC2", "qd0", "vd0", "ad0")
#: CONFIG MODE's value of each joint-controller mode.
MODES = {mode: value for value, mode in enumerate(JOINT_MODES)}
MAX_PARAM_WORDS = 12
MAX_CONFIG_RECORDS = 8


class Config(enum.IntEnum):
    """CONFIG register ids."""

    MODE       = 1   # 0 VDC, 1 PID, 2 torque-only
    TICK       = 2   # cycles per control tick (≥ 50 at 50 MHz, see docs/node.md)
    TIMEOUT    = 3   # watchdog: cycles of silence before the safe state
    RAMP       = 4   # torque decrement per tick in the safe state, FORCE LSBs
    TAU_MIN    = 5   # command limits, FORCE words
    TAU_MAX    = 6
    ARM        = 7   # 1 arms (and clears a trip), 0 disarms
    PRESET     = 8   # load the encoder count (homing)
    PRIME      = 9   # restart the VDC derivative history at the next Comm B
    PERIOD     = 10  # cycles per period of the node's timer (a multiple of TICK)
    SYNC_WINDOW = 11  # a time-code arriving at phase >= this re-synchronises the timer
    COMMIT     = 12  # phase at which an armed node commits the last Comm D
    DMP        = 13  # joint-side motion primitive (:class:`DmpControl`): off, start, stop
    DMP_STEP   = 14  # cycles per step of the primitive generator (PERIOD a multiple of it)
    STOP_CYCLES  = 15  # safe stop: time limit (cycles after a trip) of the hold before the brake
    BRAKE_CYCLES = 16  # safe stop: cycles of hold from the brake's engagement before STO
    STANDSTILL   = 17  # safe stop: standstill threshold, VEL word (|q̇| ≤ it; 0: no standstill
    #                    rule, the brake at STOP_CYCLES)
    STANDSTILL_TICKS = 18  # safe stop: consecutive ticks at standstill that engage the brake
    STOP_TRAIL   = 19  # safe stop: counts the hold's target may trail the count while stopping
    TC_DISCIPLINE = 20  # the period timer's loop on the time-code (:mod:`.discipline`; 0 off)


CONFIG_DEFAULTS = {Config.MODE: 0, Config.TICK: 50, Config.TIMEOUT: 100_000, Config.RAMP: 0,
                   Config.TAU_MIN: 0, Config.TAU_MAX: 0, Config.PERIOD: 50_000,
                   Config.SYNC_WINDOW: 2_500, Config.COMMIT: 10_000, Config.DMP: 0,
                   Config.DMP_STEP: 50_000, Config.STOP_CYCLES: 0, Config.BRAKE_CYCLES: 0,
                   Config.STANDSTILL: 0, Config.STANDSTILL_TICKS: 0,
                   Config.STOP_TRAIL: 0, Config.TC_DISCIPLINE: 0}
# (STOP_CYCLES = BRAKE_CYCLES = 0: a trip goes straight to STO, the torque ramp of a node that
# has no safe-stop upload; protocol/safe_stop.py gives the master's values.)


class DmpControl(enum.IntEnum):
    """Values of CONFIG DMP (docs/dmp.md "In the node").

    ``OFF``: the joint takes Comm D's references (the generator stops). ``START``: the
    generator starts from the primitive's start at once (its first step is computed) and its
    references replace Comm D's at the next period boundary, where its steps begin (every
    DMP_STEP cycles from each boundary). ``STOP``: the generator stops; the joint holds its last
    position reference with zero velocity and acceleration. Comm D's ``τ_D`` is used in every
    case."""

    OFF = 0
    START = 1
    STOP = 2


class Bank(enum.IntEnum):
    VDC = 0
    JOINT = 1
    DMP = 2     # the primitive generator (protocol/dmp.py)


class Status(enum.IntFlag):
    """Status bits (Comm A and Comm C)."""

    ARMED   = 1 << 0
    TRIPPED = 1 << 1   # watchdog fired: safe stop (HOLD, BRAKE, then STO) until re-armed
    SAFE    = 1 << 2   # tripped and torque zero
    FRESH   = 1 << 3   # Comm C: forces from this period's Comm B
    PRIME   = 1 << 4   # next VDC run restarts its derivative history
    MODE0   = 1 << 5   # mode, 2 bits
    MODE1   = 1 << 6
    DMP     = 1 << 7   # the joint takes its references from the primitive generator
    HOLD    = 1 << 8   # safe stop: tripped, the joint engine holds the trip position (SS1/SS2)
    BRAKE   = 1 << 9   # safe stop: the node's brake output is asserted (brake engaged)
    STOP_LIMIT = 1 << 10  # safe stop: the brake engaged at STOP_CYCLES, no standstill seen


class NodeEvent(enum.IntFlag):
    """Bits of the node's observation port (``NodeCore.events``): one-cycle strobes, test
    points only (combinational copies of existing signals; nothing reads them). Several bits
    can be set in one cycle. docs/node.md "Observation port" says what each one marks.
    """

    BOUNDARY  = 1 << 0    # period boundary: timer phase 0 or a resync (the snapshot)
    RESYNC    = 1 << 1    # the boundary was a time-code outside the sync window
    TIMECODE  = 1 << 2    # a time-code arrived (period_start strobe)
    RX_A      = 1 << 3    # last byte of a Comm A request taken
    RX_B      = 1 << 4    # last byte of a full (40-byte) Comm B taken
    RX_C      = 1 << 5    # last byte of a Comm C request taken
    RX_D      = 1 << 6    # last byte of a full Comm D taken
    VDC_START = 1 << 7    # the VDC engine starts (``vdc.start``)
    VDC_DONE  = 1 << 8    # the VDC passes its MARK: forces ready (``vdc.mark``)
    VDC_END   = 1 << 9    # the VDC program ends: adaptation and history done (``vdc.done``)
    TX_A      = 1 << 10   # the reply FSM leaves Idle with a Comm A reply
    TX_C      = 1 << 11   # the reply FSM leaves Idle with a Comm C reply
    COMMIT    = 1 << 12   # Comm D's words take effect (commit phase, or arrival disarmed)
    DMP_STEP  = 1 << 13   # a step strobe to the primitive generator (an overrun included)


def pack_words(words) -> bytes:
    """24-bit words, little-endian, two's complement."""
    # (the master and the model's nodes pack a dozen every period: the words as one integer,
    # the last one highest, then one conversion is the cheapest)
    if not isinstance(words, (list, tuple)):
        words = list(words)
    v = 0
    for w in reversed(words):
        v = (v << 24) | (int(w) & 0xFFFFFF)
    return v.to_bytes(3 * len(words), "little")


def unpack_words(data: bytes, n: int, offset: int = 0) -> list[int]:
    # all n words as one integer, then each 24-bit field sign-extended: (v ^ 0x800000) − 0x800000
    v = int.from_bytes(data[offset:offset + 3 * n], "little")
    return [(((v >> s) & 0xFFFFFF) ^ 0x800000) - 0x800000 for s in range(0, 24 * n, 24)]


def _pad(data: bytes) -> bytes:
    return data + bytes(PAYLOAD - len(data))


def _encode(x: float, shift: int) -> int:
    """:meth:`Fmt.encode <protocol.fixed.Fmt.encode>` of a format whose ``lsb`` is −``shift``
    (the same operations; the packers' words, one call each instead of a method's)."""
    w = math.floor(math.ldexp(float(x), shift) + 0.5)
    return WORD_MIN if w < WORD_MIN else WORD_MAX if w > WORD_MAX else w


_VEL_SHIFT, _ACC_SHIFT, _FORCE_SHIFT, _POS_SHIFT = -VEL.lsb, -ACC.lsb, -FORCE.lsb, -POS.lsb


def pack_comm_b(qd_r: float, V_C, V_rC, prime: bool = False) -> bytes:
    """Comm B payload from floats (rad/s, m/s; saturating at the VEL range)."""
    sh = _VEL_SHIFT
    words = [_encode(qd_r, sh), *[_encode(x, sh) for x in V_C],
             *[_encode(x, sh) for x in V_rC]]
    return pack_words(words) + (b"\1" if prime else b"\0")


def pack_comm_d(tau: float, g_C, q_d0: float, qd_d0: float, qdd_d0: float,
                counts_per_rev: int = 800_000) -> bytes:
    """Comm D payload from floats (N·m, m/s², rad, rad/s, rad/s²)."""
    counts = q_d0 * counts_per_rev / (2 * math.pi)
    words = [_encode(tau, _FORCE_SHIFT), *[_encode(x, _ACC_SHIFT) for x in g_C],
             _encode(counts, _POS_SHIFT), _encode(qd_d0, _VEL_SHIFT),
             _encode(qdd_d0, _ACC_SHIFT)]
    return _pad(pack_words(words))


def parse_comm_a(data: bytes) -> dict:
    """Fields of a Comm A reply (words left as integers; see the module docstring)."""
    if len(data) != PAYLOAD:
        raise ValueError(f"Comm A payload must be {PAYLOAD} bytes, not {len(data)}")
    qd, tau = unpack_words(data, 2, 4)
    # (one struct call for the little-endian fields from byte 10 on: the master parses three
    # to six of these a period)
    (status, errors, period, overruns, sync, late, crc, count, up, down, rx, router,
     dmp) = _COMM_A_TAIL.unpack_from(data, 10)
    return {"count": int.from_bytes(data[0:4], "little", signed=True), "qd": qd, "torque": tau,
            "status": _status(status), "errors": errors, "period": period,
            "overruns": overruns, "sync_errors": sync, "late_d": late, "upload_crc": crc,
            "upload_count": count, "up_link_errors": up, "down_link_errors": down,
            "rx_dropped": rx, "router_dropped": router, "dmp_overruns": dmp}


#: Comm A's fields from byte 10: status, errors, period, overruns, sync errors, late Comm D,
#: upload CRC and count, the four link-health counters (:data:`LINK_HEALTH`), the generator's
#: overruns
_COMM_A_TAIL = struct.Struct("<HHB10H")
assert LINK_HEALTH == ("up_link_errors", "down_link_errors", "rx_dropped", "router_dropped")
_STATUS: dict[int, Status] = {}


def _status(v: int) -> Status:
    """``Status(v)``, kept by value (the enum's call costs more than the lookup)."""
    s = _STATUS.get(v)
    if s is None:
        s = _STATUS[v] = Status(v)
    return s


def upload_check(payloads) -> tuple[int, int]:
    """``(upload_crc, upload_count)`` a node reports after taking ``payloads``, in order.

    Parameters
    ----------
    payloads : iterable of bytes
        The payloads of the CONFIG and PARAM packets the node received since reset, in
        arrival order (packets of other types do not count).

    Returns
    -------
    (int, int)
        CRC-16/CCITT-FALSE (:mod:`.crc`, initial 0xFFFF) over the concatenated
        payloads, and the number of packets modulo 2^16.
    """
    crc, n = CRC16_INIT, 0
    for p in payloads:
        crc = crc16(bytes(p), crc)
        n += 1
    return crc, n & 0xFFFF


def parse_comm_c(data: bytes) -> tuple[list[int], list[int], Status, int]:
    """``(F_a, F_b, status, period)`` of a Comm C reply (FORCE words)."""
    if len(data) != PAYLOAD:
        raise ValueError(f"Comm C payload must be {PAYLOAD} bytes, not {len(data)}")
    w = unpack_words(data, 12)
    return w[:6], w[6:], _status(int.from_bytes(data[36:38], "little")), data[38]


def config_payloads(values: dict) -> list[bytes]:
    """CONFIG payloads writing ``{Config: int}``, at most 8 records each."""
    records = []
    for key, value in values.items():
        reg = Config(key)
        v = int(value)
        if not -(1 << 31) <= v < (1 << 32):
            raise InputError(f"config.{reg.name.lower()}", f"{value!r} does not fit 32 bits")
        records.append(bytes([reg]) + (v & 0xFFFFFFFF).to_bytes(4, "little"))
    return [b"".join(records[i:i + MAX_CONFIG_RECORDS])
            for i in range(0, len(records), MAX_CONFIG_RECORDS)]


def param_payloads(bank: Bank, words: dict[int, int]) -> list[bytes]:
    """PARAM payloads writing ``{address: word}`` of a bank, contiguous runs of ≤ 12 words."""
    out = []
    addrs = sorted(words)
    i = 0
    while i < len(addrs):
        start = addrs[i]
        run = [words[start]]
        while (i + len(run) < len(addrs) and addrs[i + len(run)] == start + len(run)
               and len(run) < MAX_PARAM_WORDS):
            run.append(words[start + len(run)])
        out.append(bytes([Bank(bank)]) + start.to_bytes(2, "little") +
                   pack_words(saturate(w) for w in run))
        i += len(run)
    return out


def vdc_upload(theta, K, rho, lower, upper, period: float = 1e-3) -> list[bytes]:
    """PARAM payloads for the VDC unit from floats, checked (:class:`InputError`).

    Parameters
    ----------
    theta, lower, upper : array_like, shape (2, 13)
        Initial estimates and projection bounds (Link a, Link b).
    K : array_like, shape (2, 6)
    rho : array_like, shape (2, 13)
        Adaptation gains (zero: no adaptation).
    period : float, s
    """
    theta = np.asarray(theta, dtype=float).reshape(2, 13)
    lower = np.asarray(lower, dtype=float).reshape(2, 13)
    upper = np.asarray(upper, dtype=float).reshape(2, 13)
    K = np.asarray(K, dtype=float).reshape(2, 6)
    rho = np.asarray(rho, dtype=float).reshape(2, 13)
    if np.any(lower > upper) or np.any(theta < lower) or np.any(theta > upper):
        raise InputError("vdc.theta", "estimates must lie within lower ≤ theta ≤ upper")
    if np.any(K < 0) or np.any(rho < 0):
        raise InputError("vdc.gains", "K and rho must be non-negative")
    for i in range(2):
        for k in range(6):
            GAIN.encode_checked(K[i, k], f"vdc.K[{i}][{k}]")
        for j in range(13):
            fmt = THETA[theta_group(j)]
            for name, arr in (("theta", theta), ("lower", lower), ("upper", upper)):
                fmt.encode_checked(arr[i, j], f"vdc.{name}[{i}][{j}]")
            RHOT[theta_group(j)].encode_checked(rho[i, j] * period, f"vdc.rho[{i}][{j}]")
    params = VdcParams.from_float(K, rho, lower, upper, period)
    estimates = theta_words(theta)
    mc = vdc_microcode()
    words = {mc.addr(n): v for n, v in vdc_param_words(params).items()}
    words.update({mc.addr(f"th{L}{j}"): estimates[i][j]
                  for i, L in enumerate(LINKS) for j in range(13)})
    return param_payloads(Bank.VDC, words)


def joint_upload(params: JointParams) -> list[bytes]:
    """PARAM payloads for the joint engine."""
    mc = joint_microcode(params.pid_shift)
    return param_payloads(Bank.JOINT, {mc.addr(n): v for n, v in params.words().items()})
