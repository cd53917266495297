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


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

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
    """PIMBS: muscle boards, body-schema data, physics-informed learning, mismatch diagnosis."""


if __name__ == "__main__":
    main()
