"""Slave-node gateware: the compute core of one MRM module (docs/node.md).

Blocks, each with a bit-exact Python reference beside it (``*_ref.py``) that imports none of
the gateware; what both need is in :mod:`mrm_cosim.protocol` (number formats ``fixed``, the
register map and packet payloads ``regs``, the engine's instruction set ``isa`` and its
programs ``vdc_program`` and ``joint_program``, the ``encoder`` and ``cordic`` constants):

* :mod:`.engine` — a microcoded multiply-accumulate engine (one 24×24 multiplier made of four
  MULT18X18, a register file, a scheduled program in ROM);
* :mod:`.vdc` — the engine running the VDC program: required net force/moment of Link a and
  Link b, adaptation (its float oracle is :mod:`.vdc_float_ref`);
* :mod:`.joint` — the engine running the joint program at the control-tick rate: VDC joint
  control, PID, torque-only;
* :mod:`.encoder` — quadrature decoder and low-speed velocity estimator (reciprocal table);
* :mod:`.trig` — CORDIC sine/cosine of the joint angle;
* :mod:`.watchdog`, :mod:`.core` — safety, and the node core with its "decoded Comm B/D
  payload in, Comm A/C payload out" packet interface.
"""
