"""The command line's house rules, read from its parsers and files: each module small,
the same flag with one metavar everywhere, no abbreviations, ``--port`` and
``--virtual`` excluding each other in the parser, the exit-status table in every
``--help``."""

from __future__ import annotations

import collections
import re
from pathlib import Path

import pytest

import trajgen.cli
from trajgen.cli import build_parser

#: No module of the command line grows past this (lines): each is one command's
#: arguments and printing, or one thing the commands share.
MAX_LINES = 250

#: Flags whose metavar differs on purpose, and why.
OWN_METAVAR = {
    ("virtual-bus", "--ids"): "any number of servos on the chain, not one per joint",
}


def _commands() -> dict:
    parser = build_parser()
    return dict(parser._subparsers._group_actions[0].choices)


def test_no_command_line_module_is_over_the_limit():
    folder = Path(trajgen.cli.__file__).parent
    sizes = {p.name: len(p.read_text().splitlines()) for p in folder.glob("*.py")}
    assert len(sizes) > 10
    assert {name: n for name, n in sizes.items() if n > MAX_LINES} == {}


@pytest.mark.parametrize("name", list(_commands()))
def test_every_command_takes_no_abbreviation_and_states_its_exit_statuses(name):
    command = _commands()[name]
    assert command.allow_abbrev is False
    epilog = " ".join((command.epilog or "").split())
    assert epilog.startswith("exit status: 0 ok, 1 "), epilog
    assert "2 bad input" in epilog and ("130" in epilog), epilog
    assert "exit status: 0 ok, 1" in " ".join(command.format_help().split())


def test_a_flag_has_one_metavar_on_every_command():
    metavars = collections.defaultdict(dict)
    for name, command in _commands().items():
        for action in command._actions:
            for flag in action.option_strings:
                if (name, flag) not in OWN_METAVAR and action.metavar is not None:
                    metavars[flag][name] = action.metavar
    shared = {flag: by for flag, by in metavars.items() if len(by) > 1}
    assert {"--rate", "--json", "--plot", "--ids", "--port", "--baud"} <= set(shared)
    for flag, by in shared.items():
        if flag == "--out":  # a file of each command's own kind: OUT.csv, OUT.toml
            assert all(m.startswith("OUT.") for m in by.values()), by
        else:
            assert len(set(by.values())) == 1, (flag, by)


def test_port_and_virtual_exclude_each_other_in_every_parser():
    both = 0
    for command in _commands().values():
        flags = {f for a in command._actions for f in a.option_strings}
        if {"--port", "--virtual"} <= flags:
            both += 1
            groups = [
                {f for a in g._group_actions for f in a.option_strings}
                for g in command._mutually_exclusive_groups
            ]
            assert {"--port", "--virtual"} in groups
    assert both == 3  # stream, follow, excite


def test_every_default_in_help_has_one_of_two_shapes():
    # "default: the file's [table] key, else V" where a file may set it, "(default V)"
    # where only the flag does; never a bare "default V" or "; default V".
    shapes = re.compile(r"default: the file's \[\w+\] \w+|default: |\(default ")
    for name, command in _commands().items():
        for action in command._actions:
            if not action.help:
                continue
            text = " ".join(command._get_formatter()._expand_help(action).split())
            for found in re.finditer(r"\bdefault\b", text):
                start = max(0, found.start() - 1)
                assert shapes.match(text, start) or shapes.match(text, found.start()), (
                    name,
                    action.option_strings,
                    text,
                )
