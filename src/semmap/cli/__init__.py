"""The ``semmap`` command line: each command loads, calls one library function and saves.

This entry point only wires the commands; each lives in the module of its family (``mapping``, ``simulate``,
``train``, ``localize``, ``evaluate``, ``products``), beside the shared option types (``options``) and terminal
output (``terminal``). Known errors (bad input, bad files) print one clear line and exit with code 1; tracebacks are
for bugs.
"""

from __future__ import annotations

import functools

import typer

from semmap.cli import evaluate, localize, mapping, products, simulate, train
from semmap.cli.terminal import exit_on_errors, interruptible
from semmap.cli.terminal import setup_logging as _setup_logging  # noqa: F401  (the CLI's logging, for tests)

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="RGB-D sequences to 3D semantic maps (semantic OctoMap, .ot/.bt/native files, reports).")

#: Every command in the order ``semmap --help`` lists them (a command's name is its function's, ``_`` as ``-``).
COMMANDS = (mapping.run, simulate.simulate, mapping.demo, train.train, train.adapt, localize.track, localize.localize,
            evaluate.eval_traj, evaluate.eval_seg, evaluate.eval_map, mapping.info, mapping.batch, mapping.view,
            products.diff, products.merge)
for _command in COMMANDS:
    app.command()(_command)
app.add_typer(products.export_app, name="export")


def _checked(command: str, callback):
    """``callback`` of ``command`` with every numeric option checked against ``semmap.limits`` first, so a bad
    number is refused in one line naming the option before any work (the library checks them again), and Ctrl-C
    said in one line (typer would exit 130 without a word)."""

    @functools.wraps(callback)
    def checked(**kwargs):
        from semmap import limits

        names = _long_options(command)
        limits.check_options(command, {names.get(name, name): value for name, value in kwargs.items()})
        with interruptible():
            return callback(**kwargs)

    return checked


@functools.cache
def _long_options(command: str) -> dict[str, str]:
    """Parameter name -> ``--option`` of one command (``export grid``: a command of a sub-app)."""
    group = typer.main.get_command(app)
    for word in command.split():
        group = group.commands[word]
    return {p.name: next((o for o in p.opts if o.startswith("--")), p.name) for p in group.params}


def _command_name(info) -> str:
    return info.name or info.callback.__name__.replace("_", "-")


for _info in app.registered_commands:  # every command, present and future
    _info.callback = _checked(_command_name(_info), _info.callback)
for _group in app.registered_groups:  # and every command of a sub-app (semmap export ...)
    for _info in _group.typer_instance.registered_commands:
        _info.callback = _checked(f"{_group.name} {_command_name(_info)}", _info.callback)


def main() -> None:
    """Entry point: known errors become one line on stderr and exit code 1, Ctrl-C one line and 130."""
    exit_on_errors(app)
