"""Entry point of the `pimbs` command.

Commands are imported only when invoked, so `pimbs info` does not pay for importing torch
and a broken optional dependency of one command cannot break the others.
"""

from __future__ import annotations

import importlib

import click

# command name -> (module under `cli` that exports a click command named `command`, the
# one-line summary `pimbs --help` lists; whole, within an 80-column terminal)
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("pimbs_cli.simulate",
                 "Simulate a recording (the paper's data, or an effect hidden)."),
    "info": ("pimbs_cli.info", "Summarise recordings; refuse a broken one by name."),
    "collect": ("pimbs_cli.collect", "Collect body-schema data on the arm or the mock bus."),
    "mockbus": ("pimbs_cli.mockbus", "Run simulated muscle boards on this computer."),
    "train": ("pimbs_cli.train", "Learn the body schema from a recording."),
    "experiment": ("pimbs_cli.experiment",
                   "Reproduce the paper's Tables I–III and figures."),
    "diagnose": ("pimbs_cli.diagnose",
                 "Find why a real recording disagrees with the simulation."),
    "scan": ("pimbs_cli.scan", "List the boards heard on a port (sends nothing)."),
    "zero": ("pimbs_cli.zero", "Zero the motor encoders with the arm at its home pose."),
    "check-wiring": ("pimbs_cli.check_wiring",
                     "Pull each muscle gently; name a wrong winding direction."),
    "robot": ("pimbs_cli.robot", "Explain a robot description: joints, muscles, routing."),
    "import": ("pimbs_cli.import_log", "Turn a ROS 1 or ROS 2 bag into a recording."),
    "estimate": ("pimbs_cli.estimate",
                 "Estimate joint angles from muscle lengths and tensions."),
    "export": ("pimbs_cli.export", "Write a learned body schema as one ONNX graph."),
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
        if cmd_name not in COMMANDS:
            return None
        module_name, summary = COMMANDS[cmd_name]
        command = importlib.import_module(module_name).command
        command.short_help = summary
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list from ``COMMANDS`` alone: whole one-line summaries (click would
        cut each docstring at the terminal's width with "..."), and no command imported."""
        with formatter.section("Commands"):
            formatter.write_dl([(name, COMMANDS[name][1]) for name in self.list_commands(ctx)])


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="pimbs")
def main() -> None:
    """PIMBS: muscle boards, body-schema data, physics-informed learning, mismatch diagnosis.

    Exit status: 0 done, 1 stopped by an error (one line says what is wrong and what to
    do; a bad option or a missing file alike), 130 interrupted (Ctrl-C).
    """


if __name__ == "__main__":
    main()
