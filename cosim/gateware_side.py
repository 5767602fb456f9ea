"""The gateware side of the closed loop: what every backend does for the one loop.

:class:`GatewareSide` is the one interface the loop is written against (the pattern of
Glasgow's ``simulation/assembly.py``: an abstract assembly with a hardware and a simulation
implementation, and the applet's code written once against the abstraction). Three
implementations stand behind it:

* :class:`cosim.backends.PysimBackend` — :class:`hdl.system.System` in Amaranth's simulator;
* :class:`cosim.backends.CompiledBackend` — the same design built with Verilator;
* :class:`cosim.model.ModelBackend` — the nodes' bit-exact references with a link timing model.

Level. The interface is at *packet* level: the loop hands the master's packets and
time-codes to :meth:`GatewareSide.send` and gets back the good frames that reached the
master port (:class:`Reply`), the nodes' observation-port strobes, the torque words, the
brake outputs and the link's error counters. It is not at line or character level because
one of the three backends has no characters: the model's link is a timing model (when a
packet's last byte reaches a node, when a reply reaches the master), and giving it
characters would mean encoding every packet to characters only to decode them again, in the
backend whose whole point is speed. The two gateware backends share the character level
below the interface in one place, :class:`cosim.backends.LineSide` (framing into the master
port's FIFO, frame assembly and CRC checks, encoder lines as quadrature levels, line
faults), over their one cycle-level primitive ``run(n, inputs, outputs)``. What the master
sees — which packets, which payloads, at which cycles they leave and arrive — is the same
kind of thing on every backend, so the loop (time grid, plant, start-up, records, trace)
exists once.

Time. A backend counts cycles from its reset (cycle 0). :meth:`GatewareSide.advance` runs the
next ``n`` cycles with the encoder lines the plant drives in them (:class:`PlantLines`, one
plant step, of which the call covers cycles ``offset … offset + n − 1``); whatever was sent
before is on its way from the current cycle. Backends that run inside a simulator's
testbench (pysim) suspend in :meth:`advance`; the others never do, and :meth:`execute` runs
the loop's coroutine the way the backend is driven.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np

__all__ = ["GatewareSide", "PlantLines", "Reply", "Observed", "drive"]


class Reply(NamedTuple):
    """A good frame complete at the master port (CRC and length checked).

    Attributes
    ----------
    cycle : int
        Cycle (from reset) in which its last character arrived.
    src : int
        Sending node, 1-based.
    ptype : int
        :class:`protocol.packet.PacketType`.
    seq : int
        Sequence number in its header (a reply echoes its request's).
    payload : bytes
    """

    cycle: int
    src: int
    ptype: int
    seq: int
    payload: bytes


class Observed(NamedTuple):
    """What one :meth:`GatewareSide.advance` produced for the master.

    Attributes
    ----------
    events : list of (int, int, str)
        The nodes' observation-port strobes ``(cycle, node, NodeEvent name)``, node 1-based.
    replies : list of Reply
        Good frames at the master port, in arrival order.
    """

    events: list
    replies: list


class PlantLines:
    """The encoder lines the plant drives during one plant step, or lines at rest.

    A backend asks for the form it consumes, computed once per step and only if asked: the
    per-cycle counts and quadrature levels (:meth:`cycles`) or the count changes
    (:meth:`changes`).

    Parameters
    ----------
    plant : models.plant.Plant, optional
        A plant that has just taken its step: the lines of that step's cycles.
    counts : sequence of int, optional
        Lines at rest at these counts (one per joint), for cycles before the plant moves.
    """

    __slots__ = ("plant", "counts", "_cycles", "_changes")

    def __init__(self, plant=None, counts=None):
        if (plant is None) == (counts is None):
            raise ValueError("give either a stepped plant or the counts at rest")
        self.plant = plant
        self.counts = None if counts is None else np.asarray(counts, dtype=np.int64)
        self._cycles = None
        self._changes = None

    @property
    def at_rest(self) -> bool:
        """True for lines that do not change (:attr:`counts` holds them)."""
        return self.plant is None

    def cycles(self):
        """:class:`models.encoder.EncoderCycles` of the step (the plant's
        :meth:`~models.plant.Plant.encoder_cycles`); not for lines at rest."""
        if self._cycles is None:
            self._cycles = self.plant.encoder_cycles()
        return self._cycles

    def changes(self) -> list:
        """Per joint, the count changes ``(cycle in the step, new count)`` (the plant's
        :meth:`~models.plant.Plant.encoder_changes`); empty lists for lines at rest."""
        if self._changes is None:
            self._changes = ([[] for _ in self.counts] if self.plant is None
                             else self.plant.encoder_changes())
        return self._changes


class GatewareSide(ABC):
    """The gateware side of the closed loop (see the module docstring).

    Attributes
    ----------
    name : str
        The backend's name (``pysim``, ``compiled``, ``model``).
    crc_errors : int
        Frames the master port received and dropped (CRC, length or EEP).
    link_errors : int
        The master port codec's errors (five classes, summed).
    violations : list of str
        Conditions under which the backend's results are those of the gateware that did not
        hold during the run (the model backend's; empty for the gateware itself).
    """

    name: str = ""
    crc_errors: int = 0
    link_errors: int = 0

    @property
    def violations(self) -> list[str]:
        return []

    @abstractmethod
    def power_on(self, counts) -> None:
        """Reset (cycle 0): one node per entry of ``counts``, whose encoder lines rest at it."""

    @property
    @abstractmethod
    def link_up(self) -> bool:
        """Whether the master port's link is running (uploads can be sent)."""

    @property
    @abstractmethod
    def torque(self) -> np.ndarray:
        """The nodes' torque words in the last cycle run, N·m, shape (n,)."""

    @abstractmethod
    def brake(self) -> np.ndarray:
        """The nodes' ``brake`` outputs in the last cycle run (True: the node asks its joint's
        holding brake to engage; the safe stop's BRAKE and STO stages, docs/node.md "Safe
        stop"), bool, shape (n,)."""

    @abstractmethod
    def send(self, action) -> None:
        """The master hands ``action`` (a :class:`master.cycle.Send`: a packet or a
        time-code) to its link port in the current cycle."""

    @abstractmethod
    async def advance(self, n: int, lines: PlantLines, offset: int = 0) -> Observed:
        """Run ``n`` cycles with the encoder lines of cycles ``offset … offset + n − 1`` of
        ``lines``; returns what reached the master in them."""

    def attach_plant(self, plant) -> None:  # noqa: B027 - optional hook
        """The loop's plant (:class:`models.plant.Plant`), before its first step: a backend
        may run its step on compiled code (the model backend's kernel does)."""

    def fast_path(self, plant, rec):
        """Optional: a callable that runs whole plant steps itself, when neither the master nor
        the gateware side has anything but plain work in them (the model backend's compiled
        path): ``fast(i, stop, cycle, end_limit)`` runs the steps ``i, i + 1, …`` (before
        ``stop``) starting at ``cycle``, each ending at or before ``end_limit`` and before
        anything the backend must hand to Python, writes trace rows ``rec[0, i]`` (angles) and
        ``rec[1, i]`` (torques) and returns how many it ran (0: the loop's general step runs).
        A run may end with a step in which replies or strobes reached the master
        (:meth:`fast_observed`). Results equal the general step's bit for bit. None (the
        default): no fast path."""
        return None

    def send_ahead(self, due: int, end: int) -> bool:
        """Optional, with :meth:`fast_path`: whether the master's packets due in cycle ``due``,
        inside the plant step from the current cycle to ``end``, may be handed over now, before
        the backend runs the cycles before ``due``: nothing reaches the master in them and
        nothing in them depends on what it sends. If so, :meth:`send` takes the actions that
        follow as sent in cycle ``due`` (until the backend next runs), and the loop tries the
        fast path on the step instead of splitting it at ``due``. False (the default): the
        loop splits the step."""
        return False

    def fast_observed(self) -> Observed | None:
        """After a fast run (:meth:`fast_path`): what reached the master in its last step, for
        the loop to hand over as after :meth:`advance`; None (the default): nothing."""
        return None

    def begin(self, cycle: int, period_cycles: int) -> None:  # noqa: B027 - optional hook
        """Period 0 of the master's grid (``period_cycles`` long) starts at ``cycle``, the
        current cycle."""

    def finish(self) -> None:  # noqa: B027 - optional hook
        """The run has ended (close waveform windows, judge end-of-run conditions)."""

    def execute(self, coroutine):
        """Run the loop's ``coroutine`` to completion and return its value. Backends that
        never suspend drive it directly; a simulator backend runs it in a testbench."""
        return drive(coroutine)


def drive(coro):
    """Run a coroutine that never really suspends (the compiled and model backends) to
    completion."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value
    coro.close()
    raise RuntimeError("the closed loop suspended outside a simulator")
