"""A master for the tests that keeps every reply payload it is given (``master.payloads``)."""

from __future__ import annotations


def recording_master(robot, controller: str, trajectory, stamp: str = "period"):
    """:class:`~mrm_cosim.master.cycle.Master` with the default gains (``Gains()``), whose
    ``on_packet`` first appends ``(stamp, src, ptype, payload bytes)`` to ``master.payloads``;
    ``stamp`` is the period's index (``"period"``) or the arrival cycle (``"cycle"``)."""
    from mrm_cosim.master.cycle import Master, MasterTiming
    from mrm_cosim.master.uploads import Gains, pid_gains

    if stamp not in ("period", "cycle"):
        raise ValueError(f"stamp must be 'period' or 'cycle', not {stamp!r}")
    gains = Gains()
    master = Master(robot, controller, trajectory, robot.counts_per_rev, MasterTiming(),
                    lam=gains.lam, pid=pid_gains(robot, gains.pid_1khz_hz))
    master.payloads = []
    on_packet = master.on_packet

    def record(now, src, ptype, payload):
        key = master._rec.index if stamp == "period" else now
        master.payloads.append((key, src, ptype, bytes(payload)))
        on_packet(now, src, ptype, payload)

    master.on_packet = record
    return master
