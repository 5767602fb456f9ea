"""The ``model`` backend's link: a timing model of the chain at packet level.

The link's only job in the model is the timeline: when a packet's last byte reaches a node's
core, and when a reply reaches the master. A packet's last character reaches node k
``9 + 11 (k − 1)`` cycles plus its frame time (10 line bits per data character, 4 per EOP,
3 line bits per cycle at 150 Mbit/s) after the master's link is free (a time-code before it
holds the link for 14 bits); the node's core then takes its payload one byte per cycle, one
cycle more per word written through the engines' host port (13 for a Comm B, 3 for a Comm D,
a PARAM's words), after any packet before it; a reply leaves the node's reply FSM when the
node says (:meth:`NodeModel.reply_cycle <hdl.node.core_ref.NodeModel.reply_cycle>`) and
reaches the master ``1 + 9 + 11 (k − 1)`` cycles plus its frame time later, or its frame time
after the upstream link is free; a time-code reaches node k after ``12 k`` cycles
(docs/link.md "Per-hop latency"). These are approximations, within
:data:`EVENT_TOLERANCE` cycles of the gateware's (cosim/model.py says why that is enough).

Cuts (:meth:`LinkTiming.cut`, from ``LineFault(kind="cut")``: the same spec drives the
gateware backends). Line ``k`` (above node ``k``) cut from cycle ``c`` for ``d`` cycles is down,
in both directions, from ``c`` until the link would be back in Run: a cut of either direction
takes the whole link down (the receiver that loses the line flags a disconnect after
:data:`DISCONNECT_CYCLES`, resets and goes silent, and its peer flags the silence in turn:
docs/link.md "Disconnect detection and the exchange of silence"); once the line is whole
again both ends start over from Error-Reset, :data:`RESTART_CYCLES` to Run (Error-Reset
6.4 µs, Error-Wait 12.8 µs, the handshake 111 cycles: docs/link.md "Start-up"). Characters on
the line from ``c`` until the disconnect is flagged, or cut short by it, are lost. Once the
link is not running: the master port's packets wait in its FIFO and leave when it is back in
Run (its time-codes are not sent); a packet a node's router would send through it is
discarded and counted in that node's ``router_dropped`` (hdl/link/router.py: the whole
packet, even if the link comes back), a reply going up through line ``k`` at node ``k``, one
addressed down at node ``k − 1`` (a broadcast is taken by the node and not sent on,
uncounted). Each end of the line counts one codec error at ``c +`` :data:`DISCONNECT_CYCLES`
(node ``k``'s upstream codec, node ``k − 1``'s downstream codec or the master port's).
tests/test_safe_stop_loop.py compares it with the gateware (docs/faults.md).

Not modelled (bit level, on the gateware backends only): which error class each end counts
(a disconnect or a parity error, docs/link.md), the further disconnects each failed restart
attempt adds during a long cut of the up wires (the gateware's node below counts about one
per 32 µs of cut; this model one per cut and end), how the nodes answer the burst of requests
the FIFO held (more late replies here), the partial frame a cut truncates (the gateware
ends it with an EEP and counts it in the depacketizer's ``rx_dropped``; here it is lost
uncounted), the FIFO's depth (here it holds everything), and where in its restart cycle the
link is when the line is whole again (here: at the start of Error-Reset).
"""

from __future__ import annotations

from mrm_cosim.protocol import packet as ref

__all__ = ["LinkTiming", "LINK_UP_CYCLE", "EVENT_TOLERANCE", "frame_cycles",
           "delivery_cycles", "DISCONNECT_CYCLES", "RESTART_CYCLES"]

#: Disconnect detection, cycles after the line's last transition (``disconnect_cycles`` = 43:
#: 843–860 ns, docs/link.md "Disconnect detection").
DISCONNECT_CYCLES = 43
#: From Error-Reset to Run at standard timers: 320 + 640 + 111 cycles (docs/link.md).
RESTART_CYCLES = 1_071

#: Cycle at which the modelled link reaches Run (the gateware: about 21.4 µs at standard timers).
LINK_UP_CYCLE = 1_100
#: The modelled node events' largest distance from the gateware's, in cycles: 12 is the
#: time-code's wait for the character on the line, at most 4 cycles per hop over three hops,
#: which the packets behind it inherit; 6 measured over 20 ms of mrm3
#: (tests/test_node_events.py). The boundary, the commit and the VDC's durations are exact.
EVENT_TOLERANCE = 12
_FIRST_HOP = 9          # master tx → node 1, cycles before the first character
_HOP = 11               # per further hop
_TC_HOP = 12            # time-code, per hop
_TC_LINE = 5            # a time-code's line time (ESC + data: 14 bits), cycles
_REPLY = 1              # reply FSM leaves Idle → reply's first character offered


def frame_cycles(payload_len: int) -> int:
    """Line time of a frame (header 4 + payload + CRC 2 data characters, EOP), cycles."""
    return -(-((4 + payload_len + 2) * 10 + 4) // 3)


def delivery_cycles(ptype: int, payload_len: int) -> int:
    """Cycles from a frame's last character at the node to its last payload byte taken by the
    core: a byte per cycle, and a cycle per word the core writes through an engine's host
    port (its ``rx.ready`` is low while the word waits; the engines are idle then)."""
    words = 0
    if ptype == ref.PacketType.COMM_B and payload_len == 40:
        words = 13
    elif ptype == ref.PacketType.COMM_D:
        words = min(3, max(0, payload_len // 3 - 1))
    elif ptype == ref.PacketType.PARAM:
        words = min(12, max(0, (payload_len - 3) // 3))
    return payload_len + words


class LinkTiming:
    """The chain of ``n`` nodes as a timeline (module docstring).

    Attributes
    ----------
    inbox : list of n lists of (int, int, str, object)
        Per node, what reaches its core: ``(cycle, order, kind, data)`` with kind
        ``"timecode"`` (data: the time) or ``"packet"`` (data: ``(type, payload, seq)``);
        ``order`` puts a time-code before a packet of the same cycle. Not sorted.
    replies : list of (int, int, int, bytes, int)
        Replies on their way to the master: ``(cycle at the master, src, type, payload,
        seq)``. Not sorted.
    """

    def __init__(self, n: int):
        self.n = n
        self.inbox: list[list] = [[] for _ in range(n)]
        self.replies: list = []
        self._down_free = 0                     # master → node 1 link free from this cycle
        self._up_free = 0                       # node 1 → master link free from this cycle
        self._rx_free = [0] * n                 # node k's core takes bytes from this cycle
        #: cuts: (line k 1-based, first cycle down, first cycle its link is not running, first
        #: cycle back in Run)
        self.cuts: list[tuple[int, int, int, int]] = []
        #: what the cuts make the nodes count: (cycle, node 1-based or 0 for the master port,
        #: "up" or "down" codec error, or "router" discard), not yet taken by the caller
        self.errors: list[tuple[int, int, str]] = []
        self.lost = 0                           # packets, replies and time-codes not delivered

    def cut(self, line: int, first: int, cycles: int) -> None:
        """Line ``line`` (1-based, above that node) cut from cycle ``first`` for ``cycles``
        cycles (module docstring)."""
        if not 1 <= line <= self.n:
            raise ValueError(f"line {line} is not in a chain of {self.n} nodes")
        detect = first + DISCONNECT_CYCLES
        self.cuts.append((line, first, detect + 1, first + cycles + RESTART_CYCLES))
        self.errors.append((detect, line, "up"))
        self.errors.append((detect, line - 1, "down"))

    def _fate(self, last: int, length: int, node: int, hop: int, up: bool = False):
        """What becomes of ``length`` cycles of characters whose last one reaches node
        ``node`` (0-based) at ``last`` on the way down, or, ``up``, leaves node ``node``
        towards the master and reaches the master at ``last`` (``hop``: cycles per further
        hop): None (delivered), ``"lost"`` (on a line while it failed, or cut short when its
        link stopped), or the 1-based node whose router discards it (its port's link not
        running when it comes)."""
        for line, lo, off, hi in self.cuts:
            if line > node + 1:
                continue                    # below the node: not on the way
            # the last character at the line's upper end (up) or its lower end (down)
            t = last - hop * (line - 1) if up else last - hop * (node + 1 - line)
            if t > lo and t - length < hi:
                if t - length >= off:       # the router finds the port's link not running
                    return line if up else line - 1
                return "lost"
        return None

    def _drop(self, fate, cycle: int) -> bool:
        """Count a packet that :meth:`_fate` did not deliver; True if so."""
        if fate is None:
            return False
        self.lost += 1
        if fate != "lost" and fate >= 1:
            self.errors.append((cycle, fate, "router"))
        return True

    def _port_start(self, t: int) -> int:
        """When the master port's transmitter can start at ``t``: a packet waits in its FIFO
        while line 1's link is not running."""
        for line, _, off, hi in self.cuts:
            if line == 1 and off <= t < hi:
                t = hi
        return t

    def send(self, action, now: int) -> None:
        """The master hands ``action`` (:class:`master.cycle.Send`) to its port in cycle
        ``now``."""
        if action.kind == "timecode":
            if self.cuts and self._port_start(now) != now:
                self.lost += self.n                 # no time-code on a link not running
                return
            t = max(now, self._down_free)
            for k in range(self.n):
                at = t + _TC_HOP * (k + 1)
                if self.cuts and self._fate(at, _TC_LINE, k, _TC_HOP) is not None:
                    self.lost += 1
                    continue
                self.inbox[k].append((at, 0, "timecode", action.time))
            self._down_free = t + _TC_LINE          # the packets behind it wait for it
            return
        length = frame_cycles(len(action.payload))
        start = max(now, self._down_free)
        if self.cuts:
            start = self._port_start(start)
        t = start + length
        self._down_free = t
        dests = range(self.n) if action.dest == ref.BROADCAST else [action.dest - 1]
        for k in dests:
            if 0 <= k < self.n:
                arrive = t + _FIRST_HOP + _HOP * k
                fate = self._fate(arrive, length, k, _HOP) if self.cuts else None
                if fate is not None:
                    if action.dest == ref.BROADCAST:
                        self.lost += 1      # the router keeps its own copy, sends none down
                    else:
                        self._drop(fate, arrive)
                    continue
                taken = max(arrive, self._rx_free[k]) + \
                    delivery_cycles(action.ptype, len(action.payload))
                self._rx_free[k] = taken + 1
                self.inbox[k].append((taken, 1, "packet",
                                      (action.ptype, action.payload, action.seq)))

    def reply(self, k: int, ready: int, ptype: int, payload: bytes, seq: int) -> None:
        """Queue a reply leaving node ``k``'s (0-based) reply FSM in cycle ``ready``; like the
        gateware's, its header echoes the request's ``seq``."""
        length = frame_cycles(len(payload))
        if self.cuts:
            last = ready + _REPLY + _FIRST_HOP + _HOP * k + length
            if self._drop(self._fate(last, length, k, _HOP, up=True), ready):
                return                          # (it never reaches the master's link)
        t = max(ready + _REPLY + _FIRST_HOP + _HOP * k, self._up_free) + length
        self._up_free = t
        self.replies.append((t, k + 1, ptype, payload, seq))

    def replies_before(self, end: int) -> list:
        """The replies complete at the master before cycle ``end``, in arrival order (taken
        off the list)."""
        if not self.replies:
            return []
        self.replies.sort(key=lambda r: r[0])
        i = 0
        while i < len(self.replies) and self.replies[i][0] < end:
            i += 1
        out = self.replies[:i]
        del self.replies[:i]
        return out
