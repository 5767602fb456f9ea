"""Two codecs on independent clocks hold the link: issue 21, "a receiver that holds".

The codecs are bit-exact references (tests/test_codec_ref.py ties them to the gateware) on
clocks ``ppm`` apart, each line resampled onto the other side's sample grid
(:mod:`mrm_cosim.testbench.clocks`). 3,000 characters each way here; the 10⁶-character runs
are ``benchmarks/link_clocks.py`` (docs/link.md "Receiver margin").
"""

import pytest

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
