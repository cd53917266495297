"""The `pimbs` command line: one module per command, registered lazily by `cli.main`."""
