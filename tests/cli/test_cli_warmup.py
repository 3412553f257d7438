"""`jaxpose warmup`: the programs of `solve_pnp` and `solve` built ahead of time, found the second
time; bad counts refused in one line."""

from jaxpose.api import _programs
from jaxpose.cli._main import main


def test_warmup_builds_then_finds(capsys):
    assert main(["warmup", "--points", "12"]) == 0
    out = capsys.readouterr().out
    assert "5 programs ready" in out
    folder = _programs._folder()
    assert folder is not None and str(folder) in out.replace("\n", "")
    assert main(["warmup", "--points", "9", "16"]) == 0  # the same bucket: nothing new
    assert "5 programs ready (0 compiled, 5 found)" in capsys.readouterr().out


def test_warmup_refuses_bad_counts(capsys):
    assert main(["warmup", "--points", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxpose warmup: error: --points")
