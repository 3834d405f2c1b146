"""What every package shares: the user-error type, settings and text-file reading, and the `sdvl`
command's entry point (which loads each subcommand from the package that owns it)."""
