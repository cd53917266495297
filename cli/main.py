"""Entry point of the `pimbs` command.

Commands are imported only when invoked, so `pimbs info` does not pay for importing torch
and a broken optional dependency of one command cannot break the others.
"""

from __future__ import annotations

import importlib

import click

# command name -> module under `cli` that exports a click command named `command`
COMMANDS: dict[str, str] = {
    "simulate": "pimbs_cli.simulate",
    "info": "pimbs_cli.info",
    "collect": "pimbs_cli.collect",
    "mockbus": "pimbs_cli.mockbus",
    "train": "pimbs_cli.train",
    "experiment": "pimbs_cli.experiment",
    "diagnose": "pimbs_cli.diagnose",
    "scan": "pimbs_cli.scan",
    "zero": "pimbs_cli.zero",
    "check-wiring": "pimbs_cli.check_wiring",
    "robot": "pimbs_cli.robot",
    "import": "pimbs_cli.import_log",
    "estimate": "pimbs_cli.estimate",
    "export": "pimbs_cli.export",
}


def _one_line_usage(exc: click.UsageError) -> click.ClickException:
    """A usage error (bad option value, missing argument or path) as every other user error:
    one ``Error:`` line that names the command's --help, exit status 1.

    click's own form (usage, a hint, a blank line, then the error, exit status 2) makes a
    mistyped option look different from every other mistake and buries the line that says
    what is wrong.
    """
    where = exc.ctx.command_path if exc.ctx is not None else "pimbs"
    message = " ".join(exc.format_message().split())
    return click.ClickException(f"{message} (see `{where} --help`)")


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use, and whose usage errors
    read like every other error of the CLI (see :func:`_one_line_usage`)."""

    def make_context(self, info_name: str | None, args: list[str],
                     parent: click.Context | None = None, **extra) -> click.Context:
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as exc:
            raise _one_line_usage(exc) from exc

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:
            raise _one_line_usage(exc) from exc

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module_name = COMMANDS.get(cmd_name)
        if module_name is None:
            return None
        return importlib.import_module(module_name).command


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pimbs")
def main() -> None:
    """PIMBS: muscle boards, body-schema data, physics-informed learning, mismatch diagnosis.

    Exit status: 0 done, 1 stopped by an error (one line says what is wrong and what to
    do; a bad option or a missing file alike), 130 interrupted (Ctrl-C).
    """


if __name__ == "__main__":
    main()
