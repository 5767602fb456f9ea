"""Slave-node gateware: the compute core of one MRM module (docs/node.md).

Blocks, each with a bit-exact Python reference beside it (``*_ref.py``):

* :mod:`.fixed` — number formats (24-bit words, LSB exponents) and rounding shared by all;
* :mod:`.isa`, :mod:`.engine` — a microcoded multiply-accumulate engine (one 24×24 multiplier
  made of four MULT18X18, a register file, a scheduled program in ROM);
* :mod:`.vdc` — the VDC program: required net force/moment of Link a and Link b, adaptation;
* :mod:`.joint` — the joint program at the control-tick rate: VDC joint control, PID, torque-only;
* :mod:`.encoder` — quadrature decoder and low-speed velocity estimator (reciprocal table);
* :mod:`.trig` — CORDIC sine/cosine of the joint angle;
* :mod:`.watchdog`, :mod:`.regs`, :mod:`.core` — safety, upload registers, the node core with its
  "decoded Comm B/D payload in, Comm A/C payload out" packet interface.
"""
