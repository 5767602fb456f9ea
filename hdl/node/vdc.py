"""The VDC unit: the multiply-accumulate engine loaded with the VDC program.

The program, its entry points and register names are in :mod:`mrm_cosim.protocol.vdc_program`;
its bit-exact reference is :class:`~mrm_cosim.hdl.node.vdc_ref.VdcModel`.
"""

from mrm_cosim.protocol.vdc_program import vdc_microcode

from .engine import MacEngine

__all__ = ["VdcUnit"]


class VdcUnit(MacEngine):
    """The engine loaded with the VDC program
    (:func:`~mrm_cosim.protocol.vdc_program.vdc_microcode`)."""

    def __init__(self):
        super().__init__(vdc_microcode())
