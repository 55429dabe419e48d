"""How every command ends on an error: a user's mistake is one line and its exit status, a bug
is one line that says so (exit 70), and ``--debug`` shows the traceback."""

from __future__ import annotations

import importlib
import re
import shlex
from pathlib import Path

import pytest

from sdcnet.cli import EXIT_BUG, run_command


def raises(exc: Exception):
    def command() -> int:
        raise exc

    return command


def test_a_user_error_is_one_line_with_its_status(capsys):
    assert run_command("prog", raises(ValueError("no such split 'tset'")), {ValueError: 2}) == 2
    assert capsys.readouterr().err == "prog: error: no such split 'tset'\n"


def test_the_first_matching_kind_gives_the_status(capsys):
    errors = {FileNotFoundError: 3, OSError: 4}
    assert run_command("prog", raises(FileNotFoundError("gone")), errors) == 3
    assert run_command("prog", raises(PermissionError("denied")), errors) == 4
    assert capsys.readouterr().err.splitlines() == ["prog: error: gone", "prog: error: denied"]


def test_a_bug_says_so_in_one_line_and_debug_shows_the_traceback(capsys):
    assert run_command("prog", raises(KeyError("width")), {ValueError: 2}) == EXIT_BUG
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "prog: internal error (a bug): KeyError: 'width'; run it again with --debug for the "
        "traceback"
    ]
    assert run_command("prog", raises(KeyError("width")), {}, debug=True) == EXIT_BUG
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last)")
    assert err.splitlines()[-1] == "prog: internal error (a bug): KeyError: 'width'"
    assert run_command("prog", raises(ValueError("bad")), {ValueError: 2}, debug=True) == 2
    assert "Traceback" in capsys.readouterr().err  # a user error's traceback, on request


def _boom(*args, **kwargs):
    raise KeyError("boom")


#: command -> (its module, the name in it to replace by a function that raises KeyError,
#: arguments that reach it, where --debug goes); the training and evaluation commands need
#: torch.
COMMANDS = {
    "sdc-client": ("sdcnet.client.cli", "cmd_model", ["model", "{debug}"], None),
    "sdc-serve": ("sdcnet.service.cli", "configured_camera", ["{debug}"], None),
    "sdc-data": ("sdcnet.training.data.cli", "cmd_bench", ["{debug}", "bench"], "embreex"),
    "sdc-train": ("sdcnet.training.cli", "ship_checkpoint", ["{debug}", "ship"], "torch"),
    "sdc-eval": ("sdcnet.evaluation.cli", "write_card", ["{debug}", "card"], "torch"),
    "sdc-export": ("sdcnet.export.cli", "load_checkpoint", ["{debug}"], "torch"),
}
EXTRA_ARGS = {
    "sdc-train": ["--checkpoint", "a.pt", "--out", "b.pt"],
    "sdc-eval": ["--checkpoint", "a.pt", "--out", "card.md"],
    "sdc-export": ["--checkpoint", "a.pt", "--out", "b.onnx"],
}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_reports_a_bug_in_one_line_or_with_debug_its_traceback(
    name, monkeypatch, capsys
):
    module_name, target, argv, needs = COMMANDS[name]
    if needs:
        pytest.importorskip(needs, reason=f"{name} needs the train and data extras")
    module = importlib.import_module(module_name)
    if name == "sdc-client":  # the commands are looked up in a table built at import
        monkeypatch.setitem(module.COMMANDS, "model", _boom)
    else:
        monkeypatch.setattr(module, target, _boom)
    for debug in (False, True):
        args = [a for a in argv if a != "{debug}" or debug]
        args = ["--debug" if a == "{debug}" else a for a in args] + EXTRA_ARGS.get(name, [])
        assert module.main(args) == EXIT_BUG
        err = capsys.readouterr().err
        assert err.splitlines()[-1].startswith(f"{name}: internal error (a bug): KeyError: 'boom'")
        assert ("Traceback (most recent call last)" in err) == debug
        assert len(err.splitlines()) == 1 or debug


ROOT = Path(__file__).resolve().parents[1]


def _expand(text: str, variables: dict[str, str]) -> str:
    """``text`` with every ``$(NAME)`` of ``variables`` expanded (recursively), any other
    ``$(...)`` (a function, an automatic variable) as the word ``x``, and ``$$`` as ``$``."""
    out, i = [], 0
    while i < len(text):
        if text.startswith("$$", i):
            out.append("$")
            i += 2
        elif text.startswith("$(", i):
            depth, j = 1, i + 2
            while depth:
                depth += {"(": 1, ")": -1}.get(text[j], 0)
                j += 1
            name = text[i + 2 : j - 1]
            out.append(_expand(variables[name], variables) if name in variables else "x")
            i = j
        else:
            out.append(text[i])
            i += 1
    return "".join(out)


def makefile_commands(command: str) -> list[list[str]]:
    """The arguments of every ``command`` line in the Makefile's recipes, variables expanded."""
    text = (ROOT / "Makefile").read_text().replace("\\\n", " ")
    variables = dict(re.findall(r"^(\w+) *[?:]?= *(.*)$", text, re.MULTILINE))
    found = []
    for line in text.splitlines():
        for name, values in re.findall(r"for (\w+) in ([^;]*);", line):  # its first value
            line = line.replace(f"$${name}", _expand(values, variables).split()[0])
        lexer = shlex.shlex(_expand(line, variables), posix=True, punctuation_chars=";&|")
        words: list[str] = []
        for word in [*lexer, ";"]:  # a shell's separators end a command
            if word not in (";", "||", "&&"):
                words.append(word)
                continue
            if words[:1] == ["do"]:  # a loop's body
                words = words[1:]
            if words and words[0].endswith(f"/bin/{command}"):
                found.append(words[1:])
            words = []
    return found


@pytest.mark.parametrize(
    ("command", "module"),
    [("sdc-train", "sdcnet.training.cli"), ("sdc-eval", "sdcnet.evaluation.cli")],
)
def test_the_makefiles_commands_parse(command, module):
    """Every ``sdc-train`` and ``sdc-eval`` line of the Makefile is accepted by its parser:
    a flag renamed or a subcommand moved fails here, not in the middle of ``make model``."""
    pytest.importorskip("torch", reason=f"{command} needs the train extra")
    commands = makefile_commands(command)
    assert commands
    for argv in commands:
        importlib.import_module(module).parser().parse_args(argv)
