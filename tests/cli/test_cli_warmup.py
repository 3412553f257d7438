"""`jaxpose warmup`: the programs of `solve_pnp`, `solve` and its gradient built ahead of time,
found the second time; bad counts refused in one line."""

import re

from jaxpose.api import _programs
from jaxpose.cli._main import main


def test_warmup_builds_then_finds(capsys):
    assert main(["warmup", "--points", "12"]) == 0
    out = capsys.readouterr().out
    assert "7 programs ready" in out
    folder = _programs._folder()
    assert folder is not None and str(folder) in out.replace("\n", "")
    assert main(["warmup", "--points", "9", "16"]) == 0  # the same bucket: nothing new
    assert "7 programs ready (0 compiled, 7 found)" in capsys.readouterr().out


def test_warmup_refuses_bad_counts(capsys):
    assert main(["warmup", "--points", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxpose warmup: error: --points")


def test_warmup_track_adds_the_trackers_programs(capsys, monkeypatch):
    # --track adds the tracker's programs to the plan (here its smallest buckets, so that
    # the test compiles little); without it they are not built.
    from jaxpose.apps import _track_warmup

    small = _track_warmup.track_warm_up_plan

    def plan():
        return small(solve=(8,), refine=((8, 8),))

    monkeypatch.setattr(_track_warmup, "track_warm_up_plan", plan)
    assert main(["warmup", "--points", "12"]) == 0
    assert "7 programs ready" in capsys.readouterr().out
    assert main(["warmup", "--points", "12", "--track"]) == 0
    out = capsys.readouterr().out.replace("\n", " ")
    # (the tracker's two may already be on disk when another test of the run built them)
    found = re.search(r"9 programs ready \((\d+) compiled, (\d+) found\)", out)
    assert found and int(found[2]) >= 7, out
