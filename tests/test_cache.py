"""``mrm cache``: the backends' cache listed by entry and pruned by last use (cosim/cache.py)."""

import json
import os
import time

import pytest
from amaranth import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import Out

from mrm_cosim.cosim import cache
from mrm_cosim.errors import InputError
from mrm_cosim.mrm.cli import main

DAY = 86400.0


def _age(path, days, now):
    t = now - days * DAY
    os.utime(path, (t, t))


@pytest.fixture
def filled(tmp_path, monkeypatch):
    """A cache of every kind, entries last used 1, 10 and 40 days ago, and two unfinished
    builds (a fresh one, as if under way, and a day-old one a killed process left)."""
    root = tmp_path / "cache"
    monkeypatch.setenv("MRM_CACHE_DIR", str(root))
    now = time.time()
    for days, tag in ((1, "new"), (10, "mid"), (40, "old")):
        v = root / "verilog" / f"system3-{tag}.v"
        v.parent.mkdir(parents=True, exist_ok=True)
        v.write_text("module system; endmodule\n" * 10)
        v.with_suffix(".json").write_text("{}")
        _age(v, days, now)
        _age(v.with_suffix(".json"), days, now)
        for kind in ("verilator", "split", "numba"):
            d = root / kind / f"{kind}-{tag}"
            (d / "sub").mkdir(parents=True)
            (d / "sub" / "lib.so").write_bytes(b"x" * 1000)
            _age(d, days, now)
    for name, days in ((".system_harness-a.fresh", 0.001), (".system_harness-b.stale", 1)):
        d = root / "verilator" / name
        d.mkdir()
        (d / "half.o").write_bytes(b"y" * 10)
        _age(d, days, now)
    return root, now


def test_entries_are_listed_whole_by_kind_and_last_use(filled):
    root, _ = filled
    found = cache.entries()
    assert [e.kind for e in found] == ["verilog"] * 3 + ["verilator"] * 5 + ["split"] * 3 + \
        ["numba"] * 3
    v = [e for e in found if e.kind == "verilog"]
    assert [e.name for e in v] == ["system3-old", "system3-mid", "system3-new"]   # oldest first
    assert all(len(e.paths) == 2 for e in v)               # the .v and its .json, one entry
    assert v[0].size == len("module system; endmodule\n" * 10) + 2
    b = [e for e in found if e.kind == "verilator"]
    assert sum(e.unfinished for e in b) == 2
    assert [e.size for e in b if not e.unfinished] == [1000, 1000, 1000]


def test_prune_removes_what_was_not_used_for_so_long_and_leaves_builds_under_way(filled):
    root, now = filled
    assert cache.prune(20, dry_run=True, now=now)
    assert len(cache.entries()) == 14                       # a dry run removes nothing
    gone = cache.prune(20, now=now)
    assert sorted((e.kind, e.name) for e in gone) == sorted(
        [(k, f"{k}-old") for k in ("verilator", "split", "numba")] +
        [("verilog", "system3-old"), ("verilator", ".system_harness-b.stale")])
    assert not (root / "verilog" / "system3-old.v").exists()
    assert not (root / "verilog" / "system3-old.json").exists()
    assert (root / "verilog" / "system3-mid.v").exists()
    assert (root / "verilator" / ".system_harness-a.fresh").exists()   # may be under way
    assert not any(p.name.startswith(".") and "removing" in p.name
                   for p in (root / "verilator").iterdir())
    gone = cache.prune(5, ["verilog"], now=now)
    assert [e.name for e in gone] == ["system3-mid"]
    assert (root / "numba" / "numba-mid").exists()
    gone = cache.prune(None, now=now)                       # everything but the fresh build
    assert len(gone) == 7
    assert [e.name for e in cache.entries()] == [".system_harness-a.fresh"]


def test_prune_names_what_it_refuses(filled):
    for bad in (-1, float("nan"), "3", True):
        with pytest.raises(InputError, match="older_than: must be a number of days >= 0"):
            cache.prune(bad)
    with pytest.raises(InputError, match="kind: must be one of verilog, verilator, split, "
                       "numba, pin, not 'pip'"):
        cache.prune(1, ["pip"])
    assert len(cache.entries()) == 14


def test_a_run_taking_an_entry_marks_it_used(filled):
    """``system_verilog`` (and the Verilator builds, the split loop, the numba kernels, with
    the same call) set an entry's time when a run takes it from the cache, so an entry in
    use is never the oldest."""
    from mrm_cosim.cosim.backends import system_verilog

    class Tiny(wiring.Component):
        o: Out(4)

        def elaborate(self, platform):
            m = Module()
            r = Signal(4)
            m.d.sync += r.eq(r + 1)
            m.d.comb += self.o.eq(r)
            return m

    root, now = filled
    system_verilog(Tiny, "tiny")
    (entry,) = [e for e in cache.entries() if e.name.startswith("tiny-")]
    for path in entry.paths:
        _age(path, 30, now)
    assert [e.name for e in cache.prune(20, dry_run=True, now=now)
            if e.name.startswith("tiny-")]
    system_verilog(Tiny, "tiny")                            # taken from the cache
    assert not [e.name for e in cache.prune(20, dry_run=True, now=now)
                if e.name.startswith("tiny-")]


def test_the_command_lists_and_prunes(filled, capsys):
    root, _ = filled
    assert main(["cache", "list"]) == 0
    out = capsys.readouterr().out
    assert f"cache: {root}" in out
    assert "verilator         5" in out and "total            14" in out
    assert main(["cache", "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert listed["cache"] == str(root) and len(listed["entries"]) == 14
    assert main(["cache", "prune", "--older-than", "20", "--dry-run"]) == 0
    assert capsys.readouterr().out.startswith("would remove 5 entries")
    assert len(cache.entries()) == 14
    assert main(["cache", "prune", "--older-than", "20", "--kind", "numba", "--kind",
                 "split"]) == 0
    assert capsys.readouterr().out.startswith("removed 2 entries")
    assert main(["cache", "prune", "--all"]) == 0
    assert capsys.readouterr().out.startswith("removed 11 entries")
    assert [e.name for e in cache.entries()] == [".system_harness-a.fresh"]
