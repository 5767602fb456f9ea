"""The testbench kit: bus-functional models and helpers for simulating the project's gateware
(and yours next to it) with Amaranth's simulator.

``from mrm_cosim.testbench import PeerBench, LineMonitor, NodeMaster, run_simulation``;
docs/testbenches.md walks through a first testbench, examples/testbenches/ has four to run.
The project's own tests are written with it.
"""

from .link import (ERROR_CLASSES, CodecPair, FaultyLine, LineMonitor, LinePeer, PairBench,
                   PeerBench, RandomHost, apply_line_faults, assert_error_counts,
                   assert_link_state, assert_outputs_equal,
                   drive_codec_inputs, read_codec_outputs, token_bits)
from .node import SHORT_CODEC, UPLOAD_TYPES, NodeBench, NodeMaster
from .sim import run_simulation
from .streams import packet_ends, stream_get, stream_put

__all__ = ["stream_put", "stream_get", "packet_ends", "run_simulation", "FaultyLine",
           "CodecPair", "ERROR_CLASSES", "read_codec_outputs", "assert_outputs_equal",
           "apply_line_faults", "RandomHost", "drive_codec_inputs", "token_bits", "LinePeer",
           "LineMonitor", "PeerBench", "PairBench", "assert_link_state",
           "assert_error_counts", "NodeBench", "NodeMaster", "SHORT_CODEC", "UPLOAD_TYPES"]
