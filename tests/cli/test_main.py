"""The CLI catches the one base class: a LiteVLocError anywhere is one line on stderr, exit 2;
any other exception is a bug and keeps its traceback."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from litevloc.base.errors import LiteVLocError
from litevloc.cli import info, main
from litevloc.pipelines.evaluation.trajectory import TrajectoryError


def _run_info_raising(monkeypatch: pytest.MonkeyPatch, exc: BaseException) -> int:
    def boom(args: argparse.Namespace) -> int:
        raise exc

    monkeypatch.setattr(info, "run", boom)  # register() binds info.run when main builds the parser
    return main.main(["info"])


@pytest.mark.parametrize("exc", [
    TrajectoryError("trajectory out.txt: line 3 has 7 columns, expected 8"),  # not caught before the hierarchy
    main.UserError("bad argument --frames"),
    FileNotFoundError("no such file: x.mcap"),
])
def test_domain_errors_are_one_line_exit_2(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                           exc: BaseException) -> None:
    assert _run_info_raising(monkeypatch, exc) == 2
    err = capsys.readouterr().err
    assert err == f"litevloc info: error: {exc}\n"


def test_a_subclass_defined_anywhere_is_caught(monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    class PluginError(LiteVLocError, KeyError):
        pass

    assert _run_info_raising(monkeypatch, PluginError("plugin")) == 2
    assert capsys.readouterr().err.startswith("litevloc info: error:")


def test_other_exceptions_are_bugs_and_propagate(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ZeroDivisionError):
        _run_info_raising(monkeypatch, ZeroDivisionError("bug"))
    with pytest.raises(ValueError):  # a plain ValueError is not a domain error
        _run_info_raising(monkeypatch, ValueError("bug"))


def test_console_script_one_line_exit_2(tmp_path: Path) -> None:
    # the installed entry point, a real error from the map loader (MapFormatError)
    r = subprocess.run([sys.executable, "-m", "litevloc.cli.main", "map", "info", str(tmp_path / "nomap")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"litevloc map: error: map folder not found: {tmp_path / 'nomap'}"]
