"""Bit-exact Python references of the packet receiver and of daisy-chain forwarding.

Pure Python, fast enough for the ``model`` backend. They mirror, at transaction level, what the
gateware in :mod:`~mrm_cosim.hdl.link.packet` and :mod:`~mrm_cosim.hdl.link.router` does, on
the frames of :mod:`mrm_cosim.protocol.packet` (characters as plain integers, :data:`EOP` and
:data:`EEP` ending a packet):

* :class:`DepacketizerModel` — which packets the
  :class:`~mrm_cosim.hdl.link.packet.Depacketizer` delivers and which counter each rejected
  one bumps (:func:`~mrm_cosim.protocol.packet.check_frame`);
* :func:`route`, :class:`RouterModel`, :class:`ChainModel` — where the
  :class:`~mrm_cosim.hdl.link.router.Router` sends a packet and what it discards;
* :func:`is_packet_merge` — what an arbiter that never splits a packet may produce.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from mrm_cosim.protocol.packet import (BROADCAST, COUNTER_MAX, DEFAULT_MAX_PAYLOAD, EEP, EOP,
                                       Header, Verdict, check_frame)

__all__ = ["DepacketizerModel", "route", "RouterModel", "ChainModel", "is_packet_merge"]


class DepacketizerModel:
    """Transaction-level model of :class:`~hdl.link.packet.Depacketizer`.

    Parameters
    ----------
    max_payload : int

    Attributes
    ----------
    counts : dict of str -> int
        Saturating counters ``good``, ``crc``, ``length``, ``eep`` (as the gateware's ``stats``).
    """

    def __init__(self, *, max_payload: int = DEFAULT_MAX_PAYLOAD):
        self.max_payload = max_payload
        self.counts = {verdict.value: 0 for verdict in Verdict}
        self._partial: list[int] = []

    def feed(self, chars: Iterable[int]) -> list[tuple[Header, bytes]]:
        """Consume characters; return the packets delivered to the host, in order."""
        delivered = []
        for char in chars:
            self._partial.append(char)
            if char in (EOP, EEP):
                verdict, header, payload = check_frame(self._partial,
                                                       max_payload=self.max_payload)
                self._partial = []
                key = verdict.value
                self.counts[key] = min(self.counts[key] + 1, COUNTER_MAX)
                if verdict is Verdict.GOOD:
                    delivered.append((header, payload))
        return delivered


def route(address: int, packet: Sequence[int], *, down_running: bool = True
          ) -> tuple[bool, bool]:
    """Where a node's router sends a packet arriving on its upstream port.

    Parameters
    ----------
    address : int
        The node's address.
    packet : sequence of int
        The packet's characters; the first is the destination address.
    down_running : bool
        Whether the downstream link is in the Run state when the packet starts.

    Returns
    -------
    to_local, to_down : bool
        Both False means the packet is discarded (and counted in the router's ``dropped``).
    """
    if not packet or packet[0] > 0xFF:          # empty packet: a bare EOP/EEP
        return False, False
    dest = packet[0]
    to_local = dest == address or dest == BROADCAST
    to_down = (dest != address) and down_running
    return to_local, to_down


class RouterModel:
    """Transaction-level model of :class:`~hdl.link.router.Router` for one node.

    Packets from upstream go to the host (own address or broadcast) and/or downstream (any other
    address, broadcast included). Packets from downstream and from the host go upstream. A
    packet whose output link is not running is discarded whole and counted.
    """

    def __init__(self, address: int):
        self.address = address
        self.dropped = 0

    def _count_drop(self):
        self.dropped = min(self.dropped + 1, COUNTER_MAX)

    def from_upstream(self, packet: Sequence[int], *, down_running: bool = True
                      ) -> tuple[list[int] | None, list[int] | None]:
        """Return ``(to_local, to_down)`` copies of ``packet`` (None where it does not go)."""
        to_local, to_down = route(self.address, packet, down_running=down_running)
        if not (to_local or to_down):
            self._count_drop()
        return (list(packet) if to_local else None), (list(packet) if to_down else None)

    def to_upstream(self, packet: Sequence[int], *, up_running: bool = True
                    ) -> list[int] | None:
        """A packet from downstream or from the host, as it leaves on the upstream port."""
        if not packet or packet[0] > 0xFF or not up_running:
            self._count_drop()
            return None
        return list(packet)


class ChainModel:
    """Where packets go in a chain ``master - node 1 - ... - node n_nodes`` (all links up).

    Node ``k`` has address ``k``. Replies always travel to the master unchanged.
    """

    def __init__(self, n_nodes: int, *, max_payload: int = DEFAULT_MAX_PAYLOAD):
        if not isinstance(n_nodes, int) or not 1 <= n_nodes <= 254:
            raise ValueError(f"Node count must be an integer in 1..254, not {n_nodes!r}")
        self.routers = [RouterModel(k) for k in range(1, n_nodes + 1)]
        self.nodes = [DepacketizerModel(max_payload=max_payload) for _ in self.routers]

    def send_down(self, packet: Sequence[int]) -> dict[int, list[tuple[Header, bytes]]]:
        """Send one packet from the master; return what each node's host receives."""
        received = {}
        for index, (router, node) in enumerate(zip(self.routers, self.nodes, strict=True)):
            last = index == len(self.routers) - 1
            to_local, to_down = router.from_upstream(packet, down_running=not last)
            if to_local is not None:
                delivered = node.feed(to_local)
                if delivered:
                    received[router.address] = delivered
            if to_down is None:
                break
            packet = to_down
        return received


def is_packet_merge(output: Sequence[Sequence[int]], *sources: Sequence[Sequence[int]]) -> bool:
    """Whether ``output`` interleaves whole packets of ``sources``, each in its own order.

    That is what an arbiter that never splits a packet produces. Packets are compared by value;
    equal packets from different sources make the answer ambiguous, so give them unique contents.
    """
    heads = [0] * len(sources)
    for packet in output:
        for index, source in enumerate(sources):
            if heads[index] < len(source) and list(source[heads[index]]) == list(packet):
                heads[index] += 1
                break
        else:
            return False
    return all(head == len(source) for head, source in zip(heads, sources, strict=True))
