"""Tests for ao4d.cli: the command table, common options and how errors end."""

from __future__ import annotations

import pytest

from ao4d import cli


def test_every_command_is_listed_with_help(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert name in text


def test_a_missing_command_module_is_an_error_not_a_silent_gap(monkeypatch):
    # before: cli._load returned None for a command that failed to import ("not built yet"),
    # and the command simply vanished from `ao4d --help`
    monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + ("nope",))
    with pytest.raises(ModuleNotFoundError, match="ao4d.commands.nope"):
        cli.build_parser()


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_every_command_takes_no_progress(name):
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    assert "--no-progress" in sub.format_help()


def test_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    code = cli.main(["ao", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("ao4d ao: error: ") and "does not exist" in err
    assert err.count("\n") == 1 and "Traceback" not in err
