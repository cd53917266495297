"""The `pimbs` command line: one module per command, registered lazily by `pimbs_cli.main`."""
