"""Two codecs on independent clocks hold the link: issue 21, "a receiver that holds".

The codecs are bit-exact references (tests/test_codec_ref.py ties them to the gateware) on
clocks ``ppm`` apart, each line resampled onto the other side's sample grid
(:mod:`mrm_cosim.testbench.clocks`). 3,000 characters each way here; the 10⁶-character runs
are ``benchmarks/link_clocks.py`` (docs/link.md "Receiver margin").
"""

import numpy as np
import pytest

from mrm_cosim.hdl.link.codec_ref import CodecRef
from mrm_cosim.testbench.clocks import run_two_clocks

CHARS = 3000


@pytest.mark.parametrize("ppm", [10_000, -10_000, 100, -100])
@pytest.mark.parametrize("phase", [0.0, 0.37])
def test_link_holds_with_the_peer_clock_1_percent_and_100_ppm_away(ppm, phase):
    r = run_two_clocks(ppm, chars=CHARS, phase=phase)
    assert r.received["a"] >= CHARS and r.received["b"] >= CHARS, r
    assert r.wrong == {"a": 0, "b": 0}, r
    assert r.runs == {"a": 1, "b": 1}, "the link left Run"
    for who in "ab":
        assert not any(r.errors[who].values()), r.errors


@pytest.mark.parametrize("ppm", [100, -100])
def test_one_sample_per_bit_loses_the_link_at_100_ppm(ppm):
    """The receiver of before (3 samples per cycle at 150 Mbit/s: one sample per bit) against
    the same harness: a peer 100 ppm faster puts two transitions into one sample every 10⁴
    bits, which costs a bit, a parity or disconnect error and a restart. This is what makes the
    test above able to fail."""
    r = run_two_clocks(ppm, chars=CHARS, params={"slots": 3, "run_div": 1}, max_cycles=20_000)
    assert not r.error_free
    assert r.runs["a"] > 1 and r.runs["b"] > 1
    assert sum(r.errors["a"].values()) + sum(r.errors["b"].values()) >= 2


def test_margin_reaches_a_third_faster_peer():
    """Derived limit (docs/link.md "Receiver margin"): decoding holds while the peer's
    transitions are more than one sample apart (peer up to +100 %), framing while the peer
    sends at most 4 bits per cycle: up to +33 %."""
    r = run_two_clocks(330_000, chars=CHARS, phase=0.37)
    assert r.error_free and min(r.received.values()) >= CHARS


def test_same_clock_is_the_special_case():
    """ppm 0 and phase 0 is the common clock of every backend: the harness is then the plain
    back-to-back pair, and the characters arrive one for one."""
    r = run_two_clocks(0, chars=CHARS, phase=0.0)
    assert r.error_free and r.cycles["a"] == r.cycles["b"]


def test_error_reset_never_changes_d_and_s_together():
    """ECSS-E-ST-50-12C Rev.1 (controlled reset of an output port, for a port that enters
    ErrorReset, its clause 5.5.7.2): D and S are reset one after the other, never with a
    simultaneous transition, the delay between them no shorter than the fastest bit period and
    no longer than 500 ns. Codec a's link is disabled at 60 random moments in Run; on every slot
    of a's line no two lines change together; after each reset S falls before D, 20 ns apart,
    and the line is then silent; b counts one error per reset (the bits of a controlled reset
    may complete a character with bad parity, else b sees a disconnect) and both restart."""
    params = dict(reset_cycles=60, wait_cycles=150)
    a, b = CodecRef(**params), CodecRef(**params)
    slots = a.slots
    rng = np.random.default_rng(5)
    line = [(0, 0)]             # a's line, one entry per slot
    pulses = []
    disable_at = None
    for cycle in range(60_000):
        oa, ob = a.outputs(), b.outputs()
        line += [((oa.d_out >> i) & 1, (oa.s_out >> i) & 1) for i in range(slots)]
        if oa.running and ob.running and disable_at is None:
            disable_at = cycle + int(rng.integers(5, 60))
        pulse = disable_at is not None and cycle == disable_at
        if pulse:
            pulses.append(cycle)
            disable_at = None
        a.step(d_in=ob.d_out, s_in=ob.s_out, tx_valid=1,
               tx_payload=int(rng.integers(0, 256)) << 2, rx_ready=1, link_start=1,
               link_disable=int(pulse))
        b.step(d_in=oa.d_out, s_in=oa.s_out, tx_valid=1,
               tx_payload=int(rng.integers(0, 256)) << 2, rx_ready=1, link_start=1)
        if len(pulses) == 60 and a.outputs().running and b.outputs().running:
            break
    assert len(pulses) == 60 and a.outputs().running and b.outputs().running
    for t in range(1, len(line)):
        assert not (line[t][0] != line[t - 1][0] and line[t][1] != line[t - 1][1]), \
            f"simultaneous transition at slot {t}"
    phases = set()
    for p in pulses:
        # a enters Error-Reset at p + 1; its line of cycle p + 1 is the last it drives in Run.
        start = 1 + (p + 2) * slots
        phase = line[start - 1]
        phases.add(phase)
        window = range(start, start + 40 * slots)
        changes = [(t, line[t]) for t in window if line[t] != line[t - 1]]
        assert all(line[t] == (0, 0) for t in range(start + 2 * slots, start + 40 * slots))
        if phase == (1, 1):
            assert [v for _, v in changes] == [(1, 0), (0, 0)], "S first, then D"
            gap_ns = (changes[1][0] - changes[0][0]) * 20 / slots
            assert gap_ns == 20 and 2 * 20 / slots <= gap_ns <= 500
        else:
            assert len(changes) == sum(phase)
    assert phases == {(0, 0), (0, 1), (1, 0), (1, 1)}, "every line phase at the reset"
    assert sum(a.errors.values()) == 0
    assert sum(b.errors.values()) == 60
    assert {k for k, v in b.errors.items() if v} <= {"parity", "disconnect"}
