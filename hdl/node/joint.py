"""The joint unit: the multiply-accumulate engine loaded with the joint controller's program.

The program, its entry points (one per mode) and register names are in
:mod:`mrm_cosim.protocol.joint_program`; its bit-exact reference is
:class:`~mrm_cosim.hdl.node.joint_ref.JointModel`.
"""

from mrm_cosim.protocol.joint_program import joint_microcode

from .engine import MacEngine

__all__ = ["JointUnit"]


class JointUnit(MacEngine):
    """The engine loaded with the joint program
    (:func:`~mrm_cosim.protocol.joint_program.joint_microcode`)."""

    def __init__(self):
        super().__init__(joint_microcode())
