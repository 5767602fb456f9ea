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
    (:func:`~mrm_cosim.protocol.joint_program.joint_microcode`) of PID gain shift
    ``pid_shift`` (:func:`~mrm_cosim.protocol.joint_program.pid_formats`)."""

    def __init__(self, pid_shift: int = 0):
        self.pid_shift = pid_shift
        super().__init__(joint_microcode(pid_shift))
