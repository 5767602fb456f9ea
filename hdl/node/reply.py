"""Reply builder of the node core: Comm A and Comm C replies onto the byte stream.

A Comm A request is answered at once with the snapshot of the last period boundary
(:class:`~hdl.node.timer.Snapshot`) and what stood when the request arrived: the time-code,
the upload CRC and count, the link's health (:class:`CommAReply`). A Comm C request is
answered once the VDC run of this period's Comm B has its forces (no run requested or under
way), with the status and time-code of the request's arrival (:class:`CommCReply`; its FRESH
bit says whether a run was pending then). A Comm A goes first when both wait; each request
is kept until its reply starts, so one arriving while the previous reply is sent is not lost.
Replies go to address 0 with the request's sequence number (docs/node.md "Packets").

The payload is loaded into a shift register and sent from its low byte: cheaper on a
Virtex-II than a 40-way byte multiplexer (320 flip-flops instead of ~700 LUTs).
"""

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.packet import Beat, PacketType
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.regs import PAYLOAD

from .decoder import PacketEnd
from .timer import Snapshot

__all__ = ["ReplyBuilder", "CommAReply", "CommCReply", "LinkHealth"]


class LinkHealth(data.Struct):
    """Comm A's link-health fields (:data:`~protocol.regs.LINK_HEALTH`), saturating counts."""

    up_link_errors:   16   # the upstream codec's errors, five classes summed
    down_link_errors: 16   # the downstream codec's
    rx_dropped:       16   # frames the depacketizer dropped (CRC, length, EEP)
    router_dropped:   16   # packets the router discarded


class CommAReply(data.Struct):
    """A Comm A reply's payload, little-endian from byte 0 (zeros after it up to 40 bytes)."""

    count:        signed(32)
    velocity:     signed(WORD)
    torque:       signed(WORD)
    status:       16
    errors:       16
    period:       8
    overruns:     16
    sync_errors:  16
    late_d:       16
    upload_crc:   16
    upload_count: 16
    link:         LinkHealth
    dmp_overruns: 16


class CommCReply(data.Struct):
    """A Comm C reply's payload: ``F_a[6]``, ``F_b[6]`` (FORCE words), status, time-code."""

    forces: data.ArrayLayout(signed(WORD), 12)
    status: 16
    period: 8


class ReplyBuilder(wiring.Component):
    """Queue Comm A / Comm C requests and send their replies (see the module docstring).

    Attributes
    ----------
    requests : In(stream.Signature(PacketEnd, always_ready=True))
        Packet ends (from :class:`~hdl.node.decoder.PacketDecoder`); Comm A and Comm C count.
    snapshot : In(Snapshot)
    sync_errors : In(16)
        The period timer's snapshot and its count of re-synchronisations.
    period : In(8)
        The time-code value.
    upload_crc, upload_count : In(16)
        The decoder's upload check.
    link : In(LinkHealth)
        The link's health.
    dmp_overruns : In(16)
        Steps of the primitive generator that found its next step not ready (taken with the
        request, as the link's health).
    status : In(16)
        The node's status (:class:`~protocol.regs.Status`), without FRESH's Comm C meaning.
    forces : In(ArrayLayout(signed(24), 12))
        The VDC program's force outputs ``FA0..FA5, FB0..FB5``.
    vdc_pending : In(1)
        A VDC run is requested or under way (a Comm C reply waits).
    tx : Out(stream.Signature(Beat))
        Replies (the core's ``tx``).
    sending_a, sending_c : Out(1)
        Strobes: a Comm A / Comm C reply starts (the reply FSM leaves Idle).
    """

    requests:     In(stream.Signature(PacketEnd, always_ready=True))
    snapshot:     In(Snapshot)
    sync_errors:  In(16)
    period:       In(8)
    upload_crc:   In(16)
    upload_count: In(16)
    link:         In(LinkHealth)
    dmp_overruns: In(16)
    status:       In(16)
    forces:       In(data.ArrayLayout(signed(WORD), 12))
    vdc_pending:  In(1)
    tx:           Out(stream.Signature(Beat))
    sending_a:    Out(1)
    sending_c:    Out(1)

    def elaborate(self, platform):
        m = Module()
        req     = self.requests
        reply_a = Signal()              # requests waiting for their reply
        reply_c = Signal()
        seq_a   = Signal(8)
        seq_c   = Signal(8)
        a_period = Signal(8)            # Comm A: the fields taken with the request
        a_crc    = Signal(16)
        a_count  = Signal(16)
        a_link   = Signal(LinkHealth)
        a_dmp    = Signal(16)
        c_status = Signal(16)           # Comm C: the fields taken with the request
        c_period = Signal(8)
        payload_a = Signal(CommAReply)
        payload_c = Signal(CommCReply)
        snap = self.snapshot
        m.d.comb += [
            payload_a.count.eq(snap.count),
            payload_a.velocity.eq(snap.velocity),
            payload_a.torque.eq(snap.torque),
            payload_a.status.eq(snap.status),
            payload_a.errors.eq(snap.errors),
            payload_a.period.eq(a_period),
            payload_a.overruns.eq(snap.overruns),
            payload_a.sync_errors.eq(self.sync_errors),
            payload_a.late_d.eq(snap.late_d),
            payload_a.upload_crc.eq(a_crc),
            payload_a.upload_count.eq(a_count),
            payload_a.link.eq(a_link),
            payload_a.dmp_overruns.eq(a_dmp),
            payload_c.forces.eq(self.forces),
            payload_c.status.eq(c_status),
            payload_c.period.eq(c_period),
        ]

        r_type  = Signal(8)
        r_seq   = Signal(8)
        r_idx   = Signal(range(PAYLOAD))
        r_shift = Signal(8 * PAYLOAD)
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
                    self.sending_a.eq(reply_a),
                    self.sending_c.eq(~reply_a & reply_c & ~self.vdc_pending),
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
                with m.Elif(reply_c & ~self.vdc_pending):
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

        # Requests (after the FSM, so one arriving as the previous one is taken is not lost).
        with m.If(req.valid & (req.p.type == PacketType.COMM_A)):
            m.d.sync += [
                reply_a.eq(1),
                seq_a.eq(req.p.seq),
                a_period.eq(self.period),
                a_crc.eq(self.upload_crc),
                a_count.eq(self.upload_count),
                a_link.eq(self.link),
                a_dmp.eq(self.dmp_overruns),
            ]
        with m.If(req.valid & (req.p.type == PacketType.COMM_C)):
            # FRESH: the forces the reply will carry (it waits for a running VDC) come from
            # this period's Comm B.
            m.d.sync += [
                reply_c.eq(1),
                seq_c.eq(req.p.seq),
                c_status.eq(self.status | (self.vdc_pending << 3)),
                c_period.eq(self.period),
            ]
        return m
